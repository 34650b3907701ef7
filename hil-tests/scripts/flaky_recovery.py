#!/usr/bin/env python3
"""Measures how long hydrometrad runs on the safe inputs after each fault of the built-in `flaky`
scenario (docs/rig-emulator.md), and the link counters at the end.

    cargo build --release --bins
    python3 hil-tests/scripts/flaky_recovery.py --bin-dir target/release [--seconds 42]

Starts `hydrometrad --emulated flaky` under a private service prefix, samples its status every
10 ms with `hydrometra monitor --json --refresh-ms 10`, and prints one row per outage (safe state
entered -> left), in simulation time. Resolution: one monitor refresh (10 ms) at each end.
"""

import argparse
import json
import os
import subprocess
import sys
import time


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--bin-dir", default="target/release", help="directory with hydrometrad and hydrometra")
    p.add_argument("--seconds", type=float, default=42.0, help="how long to run (flaky's faults end at 32.6 s)")
    a = p.parse_args()
    prefix = f"hydrometra-flaky-{os.getpid()}/v1"
    daemon = subprocess.Popen(
        [os.path.join(a.bin_dir, "hydrometrad"), "--emulated", "flaky", "--service-prefix", prefix,
         "--duration", str(a.seconds + 2)],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    monitor = subprocess.Popen(
        [os.path.join(a.bin_dir, "hydrometra"), "monitor", "--service-prefix", prefix, "--json",
         "--refresh-ms", "10", "--timeout", "10"],
        stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    rows = []
    deadline = time.monotonic() + a.seconds + 10
    assert monitor.stdout is not None
    for line in monitor.stdout:
        s = json.loads(line)
        rows.append(s)
        if s["sim_time_s"] >= a.seconds or time.monotonic() > deadline:
            break
    monitor.kill()
    daemon.wait()
    if not rows:
        print("no status received", file=sys.stderr)
        return 1
    outages, start, live_seen = [], None, False
    for s in rows:
        if not s["safe_state"]:
            if start is not None:
                outages.append((start, s["sim_time_s"], start_reason))
            start, live_seen = None, True
        elif live_seen and start is None:
            start = s["sim_time_s"]
            start_reason = s["link"].get("down_reason_name", "-")
    print(f"{'lost at (s)':>11} {'back at (s)':>11} {'outage (s)':>10}  first reason")
    for lost, back, reason in outages:
        print(f"{lost:11.2f} {back:11.2f} {back - lost:10.2f}  {reason}")
    if start is not None:
        print(f"{start:11.2f} {'-':>11} {'-':>10}  still down at the end")
    c = rows[-1]["link"]
    print("counters at {:.1f} s: ".format(rows[-1]["sim_time_s"]) + ", ".join(f"{k} {v}" for k, v in c.items()
                                                                          if isinstance(v, int)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
