"""The scene services of hydrometrad (cavity mesh, flow field, particles) for Python renderers.

Written from docs/ipc.md: the header structs mirror hydrometra.v1.*Header with ctypes (same field
order and types, `type_name()` with the schema version), so iceoryx2 checks them when a service is
opened. Element counts come from the user headers: the Python binding reports a slice's length in
bytes, not elements. Used by cavity_volume.py and flow_sample.py.

    pip install 'iceoryx2==0.10.*' numpy
"""

import ctypes
import time

import numpy as np

import iceoryx2 as iox2

EVENT_TOPOLOGY = 2
EVENT_POSITIONS = 3
EVENT_FLOW = 4
EVENT_PARTICLES = 5
EVENT_SHUTDOWN = 15

# Flow field cell labels.
LABELS = ["solid", "fluid", "inflow", "outflow", "scope", "wall", "open"]
INFLOW = 2


class MeshTopologyHeader(ctypes.Structure):
    """hydrometra.v1.MeshTopologyHeader: 24 bytes."""

    _fields_ = [
        ("schema_version", ctypes.c_uint32),
        ("vertex_count", ctypes.c_uint32),
        ("triangle_count", ctypes.c_uint32),
        ("reserved0", ctypes.c_uint32),
        ("topology_revision", ctypes.c_uint64),
    ]

    @staticmethod
    def type_name() -> str:
        return "hydrometra.v1.MeshTopologyHeader"


class MeshPositionsHeader(ctypes.Structure):
    """hydrometra.v1.MeshPositionsHeader: 56 bytes."""

    _fields_ = [
        ("schema_version", ctypes.c_uint32),
        ("vertex_count", ctypes.c_uint32),
        ("status_sequence", ctypes.c_uint64),
        ("sim_time_s", ctypes.c_double),
        ("topology_revision", ctypes.c_uint64),
        ("cavity_pressure_pa", ctypes.c_double),
        ("scene_frame", ctypes.c_uint64),
        ("frame_late_s", ctypes.c_double),
    ]

    @staticmethod
    def type_name() -> str:
        return "hydrometra.v1.MeshPositionsHeader"


class FlowFieldHeader(ctypes.Structure):
    """hydrometra.v1.FlowFieldHeader: 120 bytes."""

    _fields_ = [
        ("schema_version", ctypes.c_uint32),
        ("reserved0", ctypes.c_uint32),
        ("dims", ctypes.c_uint32 * 3),
        ("cell_count", ctypes.c_uint32),
        ("origin_m", ctypes.c_double * 3),
        ("spacing_m", ctypes.c_double),
        ("status_sequence", ctypes.c_uint64),
        ("sim_time_s", ctypes.c_double),
        ("labels_offset_bytes", ctypes.c_uint64),
        ("velocities_offset_bytes", ctypes.c_uint64),
        ("total_bytes", ctypes.c_uint64),
        ("scene_frame", ctypes.c_uint64),
        ("frame_late_s", ctypes.c_double),
        ("fractions_offset_bytes", ctypes.c_uint64),
    ]

    @staticmethod
    def type_name() -> str:
        return "hydrometra.v1.FlowFieldHeader"


class Particle(ctypes.Structure):
    """hydrometra.v1.Particle: 32 bytes."""

    _fields_ = [
        ("position_m", ctypes.c_float * 3),
        ("velocity_m_per_s", ctypes.c_float * 3),
        ("kind", ctypes.c_uint32),
        ("age_s", ctypes.c_float),
    ]

    @staticmethod
    def type_name() -> str:
        return "hydrometra.v1.Particle"


class ParticlesHeader(ctypes.Structure):
    """hydrometra.v1.ParticlesHeader: 48 bytes."""

    _fields_ = [
        ("schema_version", ctypes.c_uint32),
        ("particle_count", ctypes.c_uint32),
        ("status_sequence", ctypes.c_uint64),
        ("sim_time_s", ctypes.c_double),
        ("view_clarity", ctypes.c_double),
        ("scene_frame", ctypes.c_uint64),
        ("frame_late_s", ctypes.c_double),
    ]

    @staticmethod
    def type_name() -> str:
        return "hydrometra.v1.ParticlesHeader"


for _t, _size in [(MeshTopologyHeader, 24), (MeshPositionsHeader, 56), (FlowFieldHeader, 120),
                  (Particle, 32), (ParticlesHeader, 48)]:
    assert ctypes.sizeof(_t) == _size, (_t, ctypes.sizeof(_t))


def open_service(node, name, open_fn, deadline):
    """Opens a service, retrying while the daemon has not created it yet (the scene services
    appear once the scene is ready, after `preparing`)."""
    while True:
        try:
            return open_fn(node.service_builder(iox2.ServiceName.new(name)))
        except (iox2.PublishSubscribeOpenError, iox2.EventOpenError) as e:
            error = e
        if time.monotonic() >= deadline:
            raise SystemExit(f"error: cannot open {name} ({error!r}): is hydrometrad running with "
                             "this prefix, and is its scene ready (status scene_state)?")
        time.sleep(0.1)


def open_slice(node, prefix, suffix, element, header, deadline):
    """Opens `<prefix>/<suffix>` as a slice service of `element` with user header `header`."""
    return open_service(node, f"{prefix}/{suffix}",
                        lambda b: b.publish_subscribe(iox2.Slice[element]).user_header(header).open(),
                        deadline)


def array(sample, ctype, count, offset_bytes=0):
    """A numpy copy of `count` elements of `ctype` in the sample's payload at `offset_bytes`."""
    ptr = sample.payload().as_ptr() + offset_bytes
    return np.ctypeslib.as_array((ctype * count).from_address(ptr)).copy()


def triangles(sample):
    """(topology header, triangles as an (n, 3) uint32 array) of a topology sample."""
    h = sample.user_header().contents
    return h, array(sample, ctypes.c_uint32, 3 * h.triangle_count).reshape(-1, 3)


def positions(sample):
    """(positions header, vertices as an (n, 3) float64 array in m) of a positions sample."""
    h = sample.user_header().contents
    return h, array(sample, ctypes.c_float, 3 * h.vertex_count).reshape(-1, 3).astype(np.float64)


def enclosed_volume_m3(tris, verts):
    """Volume enclosed by the closed cavity surface (normals point into the fluid, hence the minus)."""
    p0, p1, p2 = verts[tris[:, 0]], verts[tris[:, 1]], verts[tris[:, 2]]
    return -float(np.einsum("ij,ij->i", p0, np.cross(p1, p2)).sum()) / 6.0


def surface_area_m2(tris, verts):
    """Area of the cavity surface."""
    p0, p1, p2 = verts[tris[:, 0]], verts[tris[:, 1]], verts[tris[:, 2]]
    return 0.5 * float(np.linalg.norm(np.cross(p1 - p0, p2 - p0), axis=1).sum())


class FlowField:
    """A flow field sample copied out of shared memory: labels, cell-centred velocities and fluid
    volume fractions (None when the payload has none: `fractions_offset_bytes` 0)."""

    def __init__(self, sample):
        h = sample.user_header().contents
        self.dims = tuple(h.dims)
        self.origin_m = np.array(h.origin_m)
        self.spacing_m = h.spacing_m
        self.status_sequence = h.status_sequence
        self.sim_time_s = h.sim_time_s
        self.scene_frame = h.scene_frame
        n = h.cell_count
        shape = (self.dims[2], self.dims[1], self.dims[0])  # x fastest
        self.labels = array(sample, ctypes.c_uint8, n, h.labels_offset_bytes).reshape(shape)
        self.velocities = array(sample, ctypes.c_float, 3 * n, h.velocities_offset_bytes).reshape(shape + (3,))
        self.fractions = None
        if h.fractions_offset_bytes != 0 and h.fractions_offset_bytes + n <= h.total_bytes:
            raw = array(sample, ctypes.c_uint8, n, h.fractions_offset_bytes)
            self.fractions = (raw.astype(np.float64) / 255.0).reshape(shape)

    def fluid_volume_m3(self):
        """The fluid volume, sum of the fractions times the cell volume (None without fractions)."""
        if self.fractions is None:
            return None
        return float(self.fractions.sum()) * self.spacing_m ** 3

    def cell_of(self, point_m):
        """(i, j, k) of the cell containing `point_m`, or None outside the grid."""
        ijk = np.floor((np.asarray(point_m) - self.origin_m) / self.spacing_m + 0.5).astype(int)
        if np.any(ijk < 0) or np.any(ijk >= np.array(self.dims)):
            return None
        return tuple(int(v) for v in ijk)

    def sample(self, point_m):
        """Trilinear velocity (m/s) at `point_m` over the cell centres, and the nearest label."""
        g = (np.asarray(point_m) - self.origin_m) / self.spacing_m
        lo = np.floor(g).astype(int)
        if np.any(lo < 0) or np.any(lo + 1 >= np.array(self.dims)):
            return None, None
        f = g - lo
        v = np.zeros(3)
        for dk in (0, 1):
            for dj in (0, 1):
                for di in (0, 1):
                    w = (f[0] if di else 1 - f[0]) * (f[1] if dj else 1 - f[1]) * (f[2] if dk else 1 - f[2])
                    v += w * self.velocities[lo[2] + dk, lo[1] + dj, lo[0] + di]
        i, j, k = self.cell_of(point_m)
        return v, LABELS[self.labels[k, j, i]] if self.labels[k, j, i] < len(LABELS) else "unknown"

    def mean_velocity(self, label):
        """Mean velocity over the cells with `label` (e.g. INFLOW: the jet at the scope tip)."""
        mask = self.labels == label
        if not mask.any():
            return None, 0
        return self.velocities[mask].mean(axis=0), int(mask.sum())
