#!/usr/bin/env bash
# flood.sh — a connection flood does not stall streaming (issue 26): for each
# thread count, a progskin-server (TLS, sealed datagrams, the default scene)
# and progskin-flood against it: new TLS connections at --rate per second
# for --duration seconds from 127.0.0.2 onwards (handshake, Hello, Welcome,
# close) while one connected client watches its frames. Prints per thread
# count the connections welcomed, the largest gap between two frames and the
# 100 ms windows without a frame, and the server's mean tick.
#
#   scripts/flood.sh [--threads "1 2"] [--rate N] [--duration S] [--build DIR]
set -euo pipefail
cd "$(dirname "$0")/.."
BUILD=${PROGSKIN_BUILD:-build}
THREADS="1 2"
RATE=200
DURATION=10
while (($#)); do
  case "$1" in
    --threads) THREADS=$2; shift 2;;
    --rate) RATE=$2; shift 2;;
    --duration) DURATION=$2; shift 2;;
    --build) BUILD=$2; shift 2;;
    -h|--help) sed -n '2,10p' "$0" | sed 's/^# \{0,1\}//'; exit 0;;
    *) echo "flood.sh: unknown argument $1" >&2; exit 2;;
  esac
done
SERVER=$BUILD/server/progskin-server
FLOOD=$BUILD/tests/progskin-flood
NAME=flood.sh
for b in "$SERVER" "$FLOOD"; do [[ -x $b ]] || { echo "flood.sh: $b not built" >&2; exit 1; }; done
source scripts/lib.sh

printf '%-8s %-10s %-9s %-15s %-22s %s\n' threads opened welcomed largest_gap_ms windows_without_frame mean_tick_ms
status=0
for n in $THREADS; do
  # Room for the flood: every connection is welcomed then closed; the
  # per-address budgets stay at their defaults (100 addresses, 2 per second each).
  psk_start_server --threads "$n" --max-clients 1024 --duration $((DURATION + 8))
  out=$("$FLOOD" --server "127.0.0.1:$PORT" --rate "$RATE" --duration "$DURATION") || status=1
  kill -INT "$SERVER_PID" 2>/dev/null || true
  wait "$SERVER_PID" 2>/dev/null || true
  num() { sed -n "s/.*\"$1\": \([0-9.]*\).*/\1/p" <<<"$out"; }
  tick=$(sed -n 's/.*mean tick \([0-9.]*\) ms.*/\1/p' "$TMP/server.err")
  printf '%-8s %-10s %-9s %-15s %-22s %s\n' "$n" "$(num opened)" "$(num welcomed)" "$(num largest_gap_ms)" \
    "$(num windows_without_frames)/$(num windows)" "${tick:-?}"
done
exit $status
