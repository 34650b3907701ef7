#!/usr/bin/env python3
"""Samples hydrometrad's flow field at a point (docs/ipc.md, "Flow field").

    pip install 'iceoryx2==0.10.*' numpy
    python3 ipc/examples/python/flow_sample.py --point-mm 0,0,40 --count 3
    python3 ipc/examples/python/flow_sample.py --jet --count 3 --json   # the jet at the scope tip
    python3 ipc/examples/python/flow_sample.py --volume --count 3       # fluid volume vs the mesh's

`--point-mm X,Y,Z` samples trilinearly over the cell centres (organ frame, mm); `--jet` prints the
mean velocity of the inflow cells at the scope tip next to the status's view direction and inflow
port velocity of the same frame (`status_sequence`); `--volume` prints the fluid volume of the
field's fractions, sum(fraction) h^3, next to the volume the cavity mesh of the same scene frame
encloses (cavity/topology and cavity/positions, as cavity_volume.py reads them).
"""

import argparse
import ctypes
import json
import math
import sys
import time

import iceoryx2 as iox2

import hydrometra_scene as hs
from status_subscriber import Status


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--prefix", default="hydrometra/v1", help="service prefix (default hydrometra/v1)")
    parser.add_argument("--point-mm", help="x,y,z in mm, organ frame")
    parser.add_argument("--jet", action="store_true", help="the inflow jet at the scope tip")
    parser.add_argument("--volume", action="store_true",
                        help="fluid volume of the fractions vs the cavity mesh's enclosed volume")
    parser.add_argument("--count", type=int, default=0, help="stop after this many flow fields (0: until Ctrl-C)")
    parser.add_argument("--seconds", type=float, default=0.0,
                        help="stop after this many seconds of printing (0: no limit)")
    parser.add_argument("--timeout", type=float, default=300.0, help="seconds to wait for the services / data")
    parser.add_argument("--json", action="store_true", help="one JSON object per flow field")
    args = parser.parse_args()
    if not args.jet and not args.point_mm and not args.volume:
        parser.error("give --point-mm X,Y,Z, --jet or --volume")
    point = [float(v) * 1e-3 for v in args.point_mm.split(",")] if args.point_mm else None
    prefix = args.prefix.rstrip("/")

    iox2.set_log_level_from_env_or(iox2.LogLevel.Error)
    node = iox2.NodeBuilder.new().create(iox2.ServiceType.Ipc)
    deadline = time.monotonic() + args.timeout
    flow = hs.open_slice(node, prefix, "flow", ctypes.c_uint8, hs.FlowFieldHeader, deadline).subscriber_builder().create()
    status = hs.open_service(node, f"{prefix}/status", lambda b: b.publish_subscribe(Status).open(),
                             deadline).subscriber_builder().create()
    listener = hs.open_service(node, f"{prefix}/events", lambda b: b.event().open(), deadline).listener_builder().create()
    if args.volume:
        topo = hs.open_slice(node, prefix, "cavity/topology", ctypes.c_uint32,
                             hs.MeshTopologyHeader, deadline).subscriber_builder().create()
        pos = hs.open_slice(node, prefix, "cavity/positions", ctypes.c_float,
                            hs.MeshPositionsHeader, deadline).subscriber_builder().create()
    tris, revision, meshes = None, None, {}  # meshes: scene_frame -> (topology_revision, vertices)

    statuses = {}
    printed, last_data = 0, time.monotonic()
    stop_at = None
    while args.count == 0 or printed < args.count:
        if stop_at is not None and time.monotonic() >= stop_at:
            break
        listener.timed_wait(iox2.Duration.from_millis(100))
        while (s := status.receive()) is not None:
            st = s.payload().contents
            statuses[st.sequence] = (list(st.scope_view_direction), st.inflow_port_velocity_m_per_s)
        if len(statuses) > 4096:
            for k in sorted(statuses)[:-1024]:
                del statuses[k]
        if args.volume:
            while (s := topo.receive()) is not None:
                h, tris = hs.triangles(s)
                revision = h.topology_revision
            while (s := pos.receive()) is not None:
                h, verts = hs.positions(s)
                meshes[h.scene_frame] = (h.topology_revision, verts)
            for k in sorted(meshes)[:-64]:
                del meshes[k]
        field = None
        while (s := flow.receive()) is not None:
            field = hs.FlowField(s)
        if field is not None and args.volume:
            mesh = meshes.get(field.scene_frame)
            if mesh is None or tris is None or mesh[0] != revision:
                # The frame's positions (published just before its field) or topology are not
                # here yet: wait for the next field.
                field = None
        if field is None:
            if time.monotonic() - last_data > args.timeout:
                what = "with its frame's cavity mesh " if args.volume else ""
                print(f"error: no flow field {what}for {args.timeout} s", file=sys.stderr)
                return 1
            continue
        last_data = time.monotonic()
        out = {"status_sequence": field.status_sequence, "sim_time_s": field.sim_time_s}
        if point is not None:
            v, label = field.sample(point)
            out.update(point_m=point, label=label, velocity_m_per_s=None if v is None else [float(x) for x in v])
        if args.jet:
            v, cells = field.mean_velocity(hs.INFLOW)
            view, port = statuses.get(field.status_sequence, (None, None))
            out.update(inflow_cells=cells, jet_velocity_m_per_s=None if v is None else [float(x) for x in v],
                       status_view_direction=view, status_inflow_port_velocity_m_per_s=port)
        if args.volume:
            fluid = field.fluid_volume_m3()
            verts = meshes[field.scene_frame][1]
            cavity = hs.enclosed_volume_m3(tris, verts)
            f = field.fractions
            out.update(scene_frame=field.scene_frame, spacing_m=field.spacing_m,
                       fluid_volume_m3=fluid, cavity_volume_m3=cavity,
                       cavity_area_m2=hs.surface_area_m2(tris, verts),
                       fluid_cells=int((field.labels == 1).sum()),
                       scope_cells=int(((field.labels >= 2) & (field.labels <= 4)).sum()),
                       cut_cells=None if f is None else int(((f > 0) & (f < 1)).sum()))
        if args.json:
            print(json.dumps(out), flush=True)
        else:
            parts = [f"t={field.sim_time_s:.3f} s"]
            if out.get("velocity_m_per_s") is not None:
                v = out["velocity_m_per_s"]
                parts.append(f"u={[round(x, 4) for x in v]} m/s |u|={math.sqrt(sum(x * x for x in v)):.4f} ({out['label']})")
            if out.get("jet_velocity_m_per_s") is not None:
                v = out["jet_velocity_m_per_s"]
                parts.append(f"jet |u|={math.sqrt(sum(x * x for x in v)):.3f} m/s over {cells} cells; "
                             f"status port velocity {port}")
            if args.volume:
                if out["fluid_volume_m3"] is None:
                    parts.append("no fluid volume fractions in this field")
                else:
                    fluid, cavity = out["fluid_volume_m3"], out["cavity_volume_m3"]
                    parts.append(f"fluid {fluid * 1e6:.3f} ml (fractions) vs cavity mesh {cavity * 1e6:.3f} ml "
                                 f"({100 * (fluid / cavity - 1):+.1f} %)")
            print("  ".join(parts), flush=True)
        printed += 1
        if stop_at is None and args.seconds > 0:
            stop_at = time.monotonic() + args.seconds
    return 0


if __name__ == "__main__":
    sys.exit(main())
