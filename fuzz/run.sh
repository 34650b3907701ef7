#!/usr/bin/env bash
# Builds the libFuzzer targets (stable Rust: coverage instrumentation through -C passes and
# -C llvm-args, libFuzzer compiled from source by the libfuzzer-sys crate) and runs them.
#
#   fuzz/run.sh build                      build every target
#   fuzz/run.sh <target|all> <executions>  fuzz each for that many executions; one result line each
#   fuzz/run.sh smoke <seconds>            replay the committed corpus, then fuzz each for <seconds>
#   fuzz/run.sh minimize <target|all>      merge new finds into fuzz/corpus/<target>, minimised
#                                          (the smallest set of inputs covering every feature)
#   fuzz/run.sh list                       the targets
#
# New inputs go to fuzz/targets/target/work/<target> (the committed corpus is read, not written),
# crashes and hangs to fuzz/targets/target/artifacts/<target>/. Exits non-zero if any target
# crashed or hung. Extra libFuzzer flags: FUZZ_FLAGS="-only_ascii=1 ...".
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
root="$(dirname "$here")"
targets_dir="$here/targets"
triple="$(rustc -vV | sed -n 's/^host: //p')"
out="$targets_dir/target"
bin_dir="$out/$triple/release"
timeout_s=${FUZZ_TIMEOUT_S:-10}

all_targets() {
  sed -n 's/^name = "\(.*\)"$/\1/p' "$targets_dir/Cargo.toml" | grep -v '^hydrometra-fuzz-targets$'
}

build() {
  # libfuzzer-sys compiles libFuzzer from its C++ source.
  if ! command -v c++ >/dev/null 2>&1; then
    echo "run.sh: no C++ compiler (c++) for libFuzzer: apt-get install g++" >&2
    exit 2
  fi
  # --target keeps the flags off build scripts and proc macros (as cargo fuzz does).
  RUSTFLAGS="-Cpasses=sancov-module -Cllvm-args=-sanitizer-coverage-level=4 \
-Cllvm-args=-sanitizer-coverage-inline-8bit-counters -Cllvm-args=-sanitizer-coverage-pc-table \
-Cllvm-args=-sanitizer-coverage-trace-compares --cfg fuzzing -Cdebug-assertions \
-Coverflow-checks ${RUSTFLAGS:-}" \
    cargo build --release --locked --manifest-path "$targets_dir/Cargo.toml" --target "$triple" --bins
}

select_targets() {
  if [[ "$1" == all ]]; then all_targets; else
    all_targets | grep -qx "$1" || { echo "run.sh: no target '$1' (run.sh list)" >&2; exit 2; }
    echo "$1"
  fi
}

# fuzz TARGET LIBFUZZER-ARGS...: runs one target, prints its result line, returns 1 on a crash.
fuzz() {
  local t=$1; shift
  local work="$out/work/$t" art="$out/artifacts/$t" log="$out/logs/$t.log"
  mkdir -p "$work" "$art" "$(dirname "$log")"
  local start end rc=0 since="$out/logs/$t.started"
  touch "$since"
  start=$(date +%s.%N)
  "$bin_dir/$t" -timeout="$timeout_s" -rss_limit_mb=2048 -print_final_stats=1 \
    -artifact_prefix="$art/" ${FUZZ_FLAGS:-} "$@" "$work" "$here/corpus/$t" >"$log" 2>&1 || rc=$?
  end=$(date +%s.%N)
  local execs corpus crashes
  execs=$(sed -n 's/^stat::number_of_executed_units: *//p' "$log" | tail -1)
  corpus=$(( $(ls "$work" | wc -l) + $(ls "$here/corpus/$t" | wc -l) ))
  crashes=$(find "$art" -type f -newer "$since" | wc -l) # this run's, not earlier ones
  awk -v t="$t" -v n="${execs:-0}" -v s="$start" -v e="$end" -v c="$corpus" -v k="$crashes" \
    -v rc="$rc" 'BEGIN { d = e - s; printf "%-12s executions %10d  time %8.1f s  exec/s %8.0f  corpus %5d  crashes %d  (exit %d)\n", t, n, d, (d > 0 ? n / d : 0), c, k, rc }'
  if [[ $rc -ne 0 || $crashes -ne 0 ]]; then
    echo "  $t: see $log and $art/" >&2
    tail -40 "$log" >&2
    return 1
  fi
}

cmd=${1:-}
case "$cmd" in
  list) all_targets ;;
  build) build ;;
  smoke)
    seconds=${2:?run.sh smoke <seconds>}
    build
    failed=0
    for t in $(all_targets); do
      "$bin_dir/$t" -runs=0 "$here/corpus/$t" >"$out/logs-replay-$t.log" 2>&1 \
        || { echo "replay of fuzz/corpus/$t failed:" >&2; tail -40 "$out/logs-replay-$t.log" >&2; failed=1; }
      fuzz "$t" -max_total_time="$seconds" || failed=1
    done
    exit $failed
    ;;
  minimize)
    build
    for t in $(select_targets "${2:?run.sh minimize <target|all>}"); do
      new="$out/minimized/$t"
      mkdir -p "$out/work/$t"
      rm -rf "$new" && mkdir -p "$new"
      "$bin_dir/$t" -set_cover_merge=1 -timeout="$timeout_s" "$new" "$here/corpus/$t" "$out/work/$t" \
        >"$out/logs-merge-$t.log" 2>&1
      rm -rf "$here/corpus/$t" && mv "$new" "$here/corpus/$t"
      echo "$t: $(ls "$here/corpus/$t" | wc -l) inputs, $(du -sh "$here/corpus/$t" | cut -f1)"
    done
    ;;
  "" | -h | --help) sed -n '2,14p' "$0" ;;
  *)
    runs=${2:?run.sh <target|all> <executions>}
    build
    failed=0
    for t in $(select_targets "$cmd"); do
      fuzz "$t" -runs="$runs" || failed=1
    done
    exit $failed
    ;;
esac
