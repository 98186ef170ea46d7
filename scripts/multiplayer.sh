#!/usr/bin/env bash
# multiplayer.sh — players publishing their own characters on loopback: a
# catalogue-only progskin-server (--no-scene) and N progskin-client players,
# each spawning a character (Fox and CesiumMan in turn) driven by its clip and
# walking a circle of --walk diagonals; one observer (also a player) verifies
# what it displays of the others against what their publishers display at
# the same world time (--verify) and measures the latency from a publisher's
# send to its display (loopback: one clock). Prints, per observer cap: its
# measured rate, remote characters, RMS / max error in % of the diagonal and
# latency p50 / p99 (the observer's display delay pinned at 100 ms), and the
# fewest bones it displayed of a remote character on average ("bones min").
# --assets: the server's catalogue instead of Fox + CesiumMan (player i
# publishes asset i modulo their number); --cap-all: every player is capped
# at the observer's cap (a room of players on slow links), not only the observer.
#
#   scripts/multiplayer.sh [--players N] [--caps "64 0"] [--duration S] [--walk R]
#                          [--assets "A.glb B.glb"] [--cap-all] [--build DIR] [-- SERVER-ARGS...]
set -euo pipefail
cd "$(dirname "$0")/.."
BUILD=${PROGSKIN_BUILD:-build}
PLAYERS=8
CAPS="64 0"
DURATION=8
WALK=100
ASSETS=()
CAP_ALL=0
SERVER_ARGS=()
while (($#)); do
  case "$1" in
    --players) PLAYERS=$2; shift 2;;
    --caps) CAPS=$2; shift 2;;
    --duration) DURATION=$2; shift 2;;
    --walk) WALK=$2; shift 2;;
    --assets) read -r -a ASSETS <<<"$2"; shift 2;;
    --cap-all) CAP_ALL=1; shift;;
    --build) BUILD=$2; shift 2;;
    --) shift; SERVER_ARGS=("$@"); break;;
    -h|--help) sed -n '2,17p' "$0" | sed 's/^# \{0,1\}//'; exit 0;;
    *) echo "multiplayer.sh: unknown argument $1" >&2; exit 2;;
  esac
done
SERVER=$BUILD/server/progskin-server
CLIENT=$BUILD/client/progskin-client
[[ -x $SERVER && -x $CLIENT ]] || { echo "multiplayer.sh: build first (bash scripts/build.sh)" >&2; exit 1; }

NAME=multiplayer.sh
# shellcheck source=scripts/lib.sh
source scripts/lib.sh

NASSETS=2
ASSETOPT=()
if ((${#ASSETS[@]})); then
  NASSETS=${#ASSETS[@]}
  ASSETOPT=(--asset "${ASSETS[@]}")
fi

printf "%10s %12s %8s %10s %10s %10s %10s %10s\n" "cap kbit/s" "rate kbit/s" "remote" "RMS %diag" "max %diag" "p50 ms" "p99 ms" \
  "bones min"
for cap in $CAPS; do
  # TLS (the server's default, a self-signed pair in $TMP/tls): the clients pin its fingerprint.
  psk_start_server --no-scene --duration $((DURATION + 30)) "${ASSETOPT[@]}" "${SERVER_ARGS[@]}"
  SPID=$SERVER_PID
  "$CLIENT" --server 127.0.0.1:$PORT --pin "$PIN" --duration 0.2 --publish 0 --cache "$TMP/cache" >/dev/null 2>&1 || true
  OTHERS=()
  capopt=()
  [[ $cap != 0 ]] && capopt=(--max-kbps "$cap")
  playercap=()
  ((CAP_ALL)) && playercap=("${capopt[@]}")
  for i in $(seq 1 $((PLAYERS - 1))); do
    asset=$((i % NASSETS))
    "$CLIENT" --server 127.0.0.1:$PORT --pin "$PIN" --publish $asset --walk "$WALK" --duration $((DURATION + 4)) \
      --cache "$TMP/cache" --name "player$i" "${playercap[@]}" >/dev/null 2>"$TMP/p$i.err" &
    OTHERS+=($!)
    PIDS+=($!)
  done
  sleep 1
  if ! "$CLIENT" --server 127.0.0.1:$PORT --pin "$PIN" --publish 0 --walk "$WALK" --duration "$DURATION" --warmup 2 --verify \
       --verify-every 2 --delay-ms 100 --max-delay-ms 100 --report json --cache "$TMP/cache" --name observer "${capopt[@]}" >"$TMP/obs.json" 2>"$TMP/obs.err"; then
    cat "$TMP/obs.err" >&2; exit 1
  fi
  for p in "${OTHERS[@]}"; do wait "$p" || { echo "multiplayer.sh: a player failed" >&2; cat "$TMP"/p*.err >&2; exit 1; }; done
  kill $SPID 2>/dev/null || true
  wait $SPID 2>/dev/null || true
  python3 - "$TMP/obs.json" "$cap" <<'PY'
import json, sys
r = json.load(open(sys.argv[1]))
m = r["remote"]
cap = "unlimited" if sys.argv[2] == "0" else sys.argv[2]
f = lambda v: "%10.4f" % v if v is not None else "%10s" % "-"
g = lambda v: "%10.1f" % v if v is not None else "%10s" % "-"
remote = [i["bones_mean"] for i in r["instances"] if i["published"]]
print("%10s %12.1f %8d %s %s %s %s %s" % (cap, r["rate_kbps"], m["characters"], f(m["rms_pct"]), f(m["max_pct"]),
      g(m["latency_ms_p50"]), g(m["latency_ms_p99"]), g(min(remote) if remote else None)))
PY
done
