#!/usr/bin/env python3
"""A renderer-side check of hydrometrad's scene services, written from docs/ipc.md alone (with the
example module ipc/examples/python/hydrometra_scene.py). Subscribes to status, cavity/topology,
cavity/positions and flow for --seconds and prints one JSON object per received sample:

  {"kind": "topology", "revision", "triangles", "vertices", "t"}
  {"kind": "positions", "t", "revision", "pressure_pa", "volume_m3", "status": {...} | null}
  {"kind": "flow", "t", "inflow_cells", "jet", "status": {...} | null, "frame_status": {...} | null,
   "window": {"statuses", "port_min", "port_max", "open_min", "open_max", "safe_max"} | null}
  {"kind": "end", "statuses", "last_status": {...}}

"status" is the status with the sample's status_sequence (null when this subscriber did not get
it). "frame_status" is the first later status whose scene_frames is at least two past the paired
status's: it shows the scene figures (such as inflow_port_open_fraction) of the frame that
published the field or of the next one, which the paired status (taken before that frame) may not
have yet. "window" spans every status from the frame before the paired status's (the field's jet
is the mean flow since the scene's previous frame, whose inputs were taken then) through
"frame_status", with the extremes of the inflow port velocity, the open fraction and the safe
state over them (null when this subscriber missed one of them): a figure whose extremes agree
held throughout the field's frame.
hil-tests/tests/scene_stream.rs asserts on the lines.
"""

import argparse
import ctypes
import json
import os
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "..", "ipc", "examples", "python"))

import iceoryx2 as iox2  # noqa: E402

import hydrometra_scene as hs  # noqa: E402
from status_subscriber import Status  # noqa: E402


def brief(s):
    return {
        "sequence": s.sequence,
        "cavity_pressure_pa": s.cavity_pressure_pa,
        "cavity_volume_m3": s.cavity_volume_m3,
        "cavity_surface_volume_m3": s.cavity_surface_volume_m3,
        "inflow_port_velocity_m_per_s": s.inflow_port_velocity_m_per_s,
        "inflow_port_open_fraction": s.inflow_port_open_fraction,
        "scene_frames": s.scene_frames,
        "scope_view_direction": list(s.scope_view_direction),
        "scope_tip_position_m": list(s.scope_tip_position_m),
        "valve_in_opening": s.valve_in_opening,
        "valve_out_opening": s.valve_out_opening,
        "safe_state": s.safe_state,
        "scene_state": s.scene_state,
        "scene_stage_runs": list(s.scene_stage_runs),
        "scene_stage_skips": list(s.scene_stage_skips),
        "scene_stage_p99_s": list(s.scene_stage_p99_s),
        "deadline_misses": s.deadline_misses,
        "ticks": s.ticks,
    }


def frame_status(statuses, seq, newest):
    """The first status after `seq` (gaps allowed) whose scene_frames is two past status `seq`'s."""
    base = statuses.get(seq)
    if base is None:
        return None
    for later in range(seq + 1, newest + 1):
        s = statuses.get(later)
        if s is not None and s["scene_frames"] >= base["scene_frames"] + 2:
            return s
    return None


def window(statuses, seq, frame):
    """Extremes of the figures a field's jet depends on over its whole frame: the statuses from the
    last one before any showing the frame ahead of status `seq`'s (the field's hydraulic interval
    begins at the scene's previous frame) through `frame`; None if one of them is missing."""
    base = statuses.get(seq)
    if base is None or frame is None:
        return None
    first = seq
    while True:
        s = statuses.get(first - 1)
        if s is None:
            return None
        first -= 1
        if s["scene_frames"] < base["scene_frames"] - 1:
            break
    span = [statuses.get(k) for k in range(first, frame["sequence"] + 1)]
    if any(s is None or s["inflow_port_open_fraction"] != s["inflow_port_open_fraction"] for s in span):
        return None  # a missed status, or no open fraction yet (NaN before the scene runs)
    port = [s["inflow_port_velocity_m_per_s"] for s in span]
    open_ = [s["inflow_port_open_fraction"] for s in span]
    return {"statuses": len(span), "port_min": min(port), "port_max": max(port),
            "open_min": min(open_), "open_max": max(open_),
            "safe_max": max(s["safe_state"] for s in span)}


def main() -> int:
    p = argparse.ArgumentParser()
    p.add_argument("--prefix", required=True)
    p.add_argument("--seconds", type=float, required=True)
    p.add_argument("--timeout", type=float, default=120.0)
    args = p.parse_args()
    prefix = args.prefix.rstrip("/")
    iox2.set_log_level_from_env_or(iox2.LogLevel.Error)
    node = iox2.NodeBuilder.new().create(iox2.ServiceType.Ipc)
    deadline = time.monotonic() + args.timeout
    status = hs.open_service(node, f"{prefix}/status", lambda b: b.publish_subscribe(Status).open(),
                             deadline).subscriber_builder().create()
    topo = hs.open_slice(node, prefix, "cavity/topology", ctypes.c_uint32, hs.MeshTopologyHeader,
                         deadline).subscriber_builder().create()
    pos = hs.open_slice(node, prefix, "cavity/positions", ctypes.c_float, hs.MeshPositionsHeader,
                        deadline).subscriber_builder().create()
    flow = hs.open_slice(node, prefix, "flow", ctypes.c_uint8, hs.FlowFieldHeader,
                         deadline).subscriber_builder().create()
    listener = hs.open_service(node, f"{prefix}/events", lambda b: b.event().open(),
                               deadline).listener_builder().create()
    print(json.dumps({"kind": "ready", "t": time.monotonic()}), flush=True)

    statuses, count, last, newest = {}, 0, None, -1
    tris, revision = None, None
    pending = []  # samples waiting for their status (and flow fields for their frame's status)
    end = time.monotonic() + args.seconds
    while time.monotonic() < end:
        listener.timed_wait(iox2.Duration.from_millis(5))
        now = time.monotonic()
        while (s := status.receive()) is not None:
            st = s.payload().contents
            statuses[st.sequence] = brief(st)
            last = statuses[st.sequence]
            newest = max(newest, st.sequence)
            count += 1
        while (s := topo.receive()) is not None:
            h, tris = hs.triangles(s)
            revision = h.topology_revision
            print(json.dumps({"kind": "topology", "t": now, "revision": revision,
                              "triangles": len(tris), "vertices": h.vertex_count}), flush=True)
        while (s := pos.receive()) is not None:
            h, verts = hs.positions(s)
            volume = hs.enclosed_volume_m3(tris, verts) if tris is not None and h.topology_revision == revision else None
            pending.append(({"kind": "positions", "t": now, "revision": h.topology_revision,
                             "pressure_pa": h.cavity_pressure_pa, "volume_m3": volume}, h.status_sequence, now))
        while (s := flow.receive()) is not None:
            f = hs.FlowField(s)
            jet, cells = f.mean_velocity(hs.INFLOW)
            pending.append(({"kind": "flow", "t": now, "inflow_cells": cells,
                             "jet": None if jet is None else [float(x) for x in jet]}, f.status_sequence, now))
        # A sample's status may arrive a little after the sample: wait up to 50 ms for it; a flow
        # field also waits up to 300 ms for the status of its frame.
        keep = []
        for line, seq, at in pending:
            done = seq in statuses or now - at > 0.05
            if done and line["kind"] == "flow":
                line["frame_status"] = frame_status(statuses, seq, newest)
                line["window"] = window(statuses, seq, line["frame_status"])
                done = line["frame_status"] is not None or now - at > 0.3
            if done:
                line["status"] = statuses.get(seq)
                print(json.dumps(line), flush=True)
            else:
                keep.append((line, seq, at))
        pending = keep
        if len(statuses) > 20000:
            for k in sorted(statuses)[:-5000]:
                del statuses[k]
    print(json.dumps({"kind": "end", "statuses": count, "last_status": last}), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
