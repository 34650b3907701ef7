#!/bin/bash
# The daemon's CPU at rest (issue 13): the emulated rig in its own process on a pseudo-terminal
# playing docs/bench/closed-valves.toml, hydrometrad on it; prints utime + stime of the daemon as
# % of one core over 20 s after 8 s of settling, and the same per thread.
# usage: docs/bench/idle-cpu.sh BIN_DIR TAG [hydrometrad args...]
#   e.g. docs/bench/idle-cpu.sh target/release B1 --scene default --atlas-cache-dir target/hil-atlas
set -u
B=$1; TAG=$2; shift 2
HERE=$(cd "$(dirname "$0")" && pwd)
T=$(mktemp -d)
"$B/hydrometra" rig emulate --scenario "$HERE/closed-valves.toml" --link "$T/rig" --seconds 45 > "$T/emulator.log" 2>&1 &
E=$!
sleep 1
"$B/hydrometrad" --device "$T/rig" --no-record --duration 32 --service-prefix "idle/$TAG-$$" "$@" > "$T/daemon.log" 2>&1 &
P=$!
threads() { for t in /proc/$P/task/*; do echo "$(cat "$t/comm"):$(basename "$t") $(awk '{print $14+$15}' "$t/stat")"; done | sort; }
sleep 8
threads > "$T/threads-a"; a=$(awk '{print $14+$15}' /proc/$P/stat)
sleep 20
threads > "$T/threads-b"; b=$(awk '{print $14+$15}' /proc/$P/stat)
per=$(join "$T/threads-a" "$T/threads-b" | awk '{d=$3-$2; if (d>0) printf "%s=%.2f ", $1, d/20}')
# Clock ticks are 10 ms: (ticks over 20 s) / 20 is % of one core.
echo "$TAG daemon $(echo "scale=2; ($b-$a)/20" | bc) % [$per]"
wait $P; kill $E 2>/dev/null; wait $E 2>/dev/null
rm -rf "$T"
