#!/usr/bin/env bash
# perf_under.sh — where the time under one function goes: records a
# benchmark with call stacks (perf record --call-graph dwarf) and counts,
# over the samples whose stack holds FRAME, the first function that is not
# inlined (its self time), as a share of those samples. For a benchmark that
# pauses its timer around work it does not measure (BM_ClientTick pauses
# around the frame's encoding), a plain perf report mixes the two; this
# counts only what runs under FRAME. docs/performance.md "The packer's bit
# copies and the scheduler's heap".
#
#   scripts/perf_under.sh FRAME BENCHMARK_BINARY [BENCHMARK ARGS...]
#   e.g. scripts/perf_under.sh ClientStream::tick build/bench/bench_net_server \
#            --benchmark_filter='ClientTick/20000/0' --benchmark_min_time=2
#
# Exit: 0 with the table; 2 on bad arguments; 1 when perf fails or no sample
# holds FRAME.
set -euo pipefail
if [[ $# -lt 2 || "$1" == "--help" || "$1" == "-h" ]]; then
  sed -n '2,16p' "$0" | sed 's/^# \{0,1\}//'
  [[ $# -ge 1 && ( "$1" == "--help" || "$1" == "-h" ) ]] && exit 0 || exit 2
fi
frame=$1; shift
data=$(mktemp /tmp/perf_under.XXXXXX)
trap 'rm -f "$data"' EXIT
# -D 2000: past the benchmark's asset build.
perf record -q --call-graph dwarf,16384 -F 300 -D 2000 -o "$data" "$@" >/dev/null 2>&1 || { echo "perf_under: perf record failed" >&2; exit 1; }
perf script -i "$data" 2>/dev/null | awk -v frame="$frame" '
  function flush() {
    if (held && first != "") { n++; count[first]++ }
    held = 0; first = ""
  }
  /^[^ \t]/ { flush(); next }              # a sample header line
  /^$/ { flush(); next }
  {
    if (index($0, frame) > 0) held = 1
    if (first == "" && $0 !~ /\(inlined\)/) {
      line = $0; sub(/^[ \t]*[0-9a-f]+ /, "", line); sub(/\+0x[0-9a-f]+ \(.*$/, "", line); first = line
    }
  }
  END {
    flush()
    if (n == 0) { print "perf_under: no sample holds " frame > "/dev/stderr"; exit 1 }
    printf "%d samples under %s\n", n, frame
    for (f in count) printf "%6.1f %%  %s\n", 100 * count[f] / n, f
  }' | { read -r head; echo "$head"; sort -rn | head -20; }
