#!/usr/bin/env bash
# time_to_listen.sh — seconds from starting progskin-server until it prints its
# "listening" line (all assets loaded), best of N runs (docs/performance.md).
#
# usage: scripts/time_to_listen.sh [-n RUNS] [--] SERVER_ARGS...
#   e.g. scripts/time_to_listen.sh -n 3 --asset fox_progressive.glb
# Environment: PROGSKIN_SERVER (default build/server/progskin-server).
set -euo pipefail
runs=3
if [[ "${1:-}" == "-n" ]]; then runs=$2; shift 2; fi
[[ "${1:-}" == "--" ]] && shift
server=${PROGSKIN_SERVER:-build/server/progskin-server}
[[ -x "$server" ]] || { echo "time_to_listen.sh: $server not built" >&2; exit 1; }
best=""
tls_dir=$(mktemp -d)  # the server's default self-signed TLS pair, out of the user's config directory
trap 'rm -rf "$tls_dir"' EXIT
for ((i = 0; i < runs; ++i)); do
  start=$(date +%s.%N)
  t=""
  while IFS= read -r line; do
    if [[ "$line" == *listening* ]]; then t=$(echo "$(date +%s.%N) - $start" | bc -l); fi
  done < <("$server" --port 0 --duration 0.05 --tls-dir "$tls_dir" "$@" 2>/dev/null)
  [[ -n "$t" ]] || { echo "time_to_listen.sh: the server did not start (run it by hand to see why)" >&2; exit 1; }
  if [[ -z "$best" ]] || (( $(echo "$t < $best" | bc -l) )); then best=$t; fi
done
printf '%.3f\n' "$best"
