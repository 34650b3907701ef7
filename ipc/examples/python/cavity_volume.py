#!/usr/bin/env python3
"""Reconstructs hydrometrad's cavity mesh from cavity/topology and cavity/positions and prints the
volume it encloses (docs/ipc.md, "Cavity mesh").

    pip install 'iceoryx2==0.10.*' numpy
    python3 ipc/examples/python/cavity_volume.py --count 5
    python3 ipc/examples/python/cavity_volume.py --count 5 --json

The topology arrives once (history 1 gives it to a late subscriber); positions every scene frame.
Positions are paired with the topology of the same `topology_revision`.
"""

import argparse
import ctypes
import json
import sys
import time

import iceoryx2 as iox2

import hydrometra_scene as hs
from status_subscriber import PA_PER_MMHG


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--prefix", default="hydrometra/v1", help="service prefix (default hydrometra/v1)")
    parser.add_argument("--count", type=int, default=0, help="stop after this many frames (0: until Ctrl-C)")
    parser.add_argument("--timeout", type=float, default=300.0,
                        help="seconds to wait for the services (a first start builds the atlas) / for data")
    parser.add_argument("--json", action="store_true", help="one JSON object per frame")
    args = parser.parse_args()
    prefix = args.prefix.rstrip("/")

    iox2.set_log_level_from_env_or(iox2.LogLevel.Error)
    node = iox2.NodeBuilder.new().create(iox2.ServiceType.Ipc)
    deadline = time.monotonic() + args.timeout
    topo = hs.open_slice(node, prefix, "cavity/topology", ctypes.c_uint32,
                         hs.MeshTopologyHeader, deadline).subscriber_builder().create()
    pos = hs.open_slice(node, prefix, "cavity/positions", ctypes.c_float,
                        hs.MeshPositionsHeader, deadline).subscriber_builder().create()
    listener = hs.open_service(node, f"{prefix}/events", lambda b: b.event().open(), deadline).listener_builder().create()

    tris, revision, printed = None, None, 0
    last_data = time.monotonic()
    while args.count == 0 or printed < args.count:
        listener.timed_wait(iox2.Duration.from_millis(100))
        while (s := topo.receive()) is not None:
            h, tris = hs.triangles(s)
            revision = h.topology_revision
        newest = None
        while (s := pos.receive()) is not None:
            newest = hs.positions(s)
        if newest is not None and tris is not None:
            h, verts = newest
            if h.topology_revision != revision:
                continue  # positions of another topology: wait for its topology
            volume = hs.enclosed_volume_m3(tris, verts)
            if args.json:
                print(json.dumps({"status_sequence": h.status_sequence, "sim_time_s": h.sim_time_s,
                                  "cavity_pressure_pa": h.cavity_pressure_pa, "vertices": len(verts),
                                  "triangles": len(tris), "topology_revision": revision,
                                  "volume_m3": volume}), flush=True)
            else:
                print(f"t={h.sim_time_s:.3f} s  {h.cavity_pressure_pa / PA_PER_MMHG:6.1f} mmHg  "
                      f"{len(verts)} vertices, {len(tris)} triangles  enclosed volume {volume * 1e6:.3f} ml",
                      flush=True)
            printed += 1
            last_data = time.monotonic()
        if time.monotonic() - last_data > args.timeout:
            print(f"error: no cavity frame for {args.timeout} s", file=sys.stderr)
            return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
