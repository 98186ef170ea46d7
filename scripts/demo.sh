#!/usr/bin/env bash
# demo.sh — the streaming demo: a progskin-server with the default character
# set (assets/Fox.glb: Survey, Walk, Run; assets/CesiumMan.glb) and one
# progskin-client per bandwidth cap on loopback, all at once, each verifying
# what it displays against the reference. Prints the rate-distortion table:
# cap -> measured rate (docs/metrics.md §3: UDP payload + 28 bytes per datagram), bones
# per character, RMS and max error in % of the rest-pose diagonal.
#
#   scripts/demo.sh [--duration S] [--caps "16 32 64 ..."] [--build DIR] [-- SERVER-ARGS...]
#
# SERVER-ARGS go to progskin-server (e.g. -- --build-strategy rate --key-samples).
#
# Builds the three targets into build/ if they are missing. Finishes in well
# under a minute and stops every process it started.
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT=$(pwd)
BUILD=${PROGSKIN_BUILD:-build}
DURATION=8
CAPS="16 24 32 48 64 96 128 192 256 0"
SERVER_ARGS=()
while (($#)); do
  case "$1" in
    --duration) DURATION=$2; shift 2;;
    --caps) CAPS=$2; shift 2;;
    --build) BUILD=$2; shift 2;;
    --) shift; SERVER_ARGS=("$@"); break;;
    -h|--help) sed -n '2,14p' "$0" | sed 's/^# \{0,1\}//'; exit 0;;
    *) echo "demo.sh: unknown argument $1" >&2; exit 2;;
  esac
done

SERVER=$BUILD/server/progskin-server
CLIENT=$BUILD/client/progskin-client
if [[ ! -x $SERVER || ! -x $CLIENT ]]; then
  echo "demo: building progskin-server and progskin-client into $BUILD ..." >&2
  bash scripts/setup.sh
  cmake -S . -B "$BUILD" -DCMAKE_BUILD_TYPE=RelWithDebInfo >/dev/null
  cmake --build "$BUILD" -j"$(nproc)" --target progskin-server progskin-client >/dev/null
fi

NAME=demo
# shellcheck source=scripts/lib.sh
source scripts/lib.sh
# TLS (the server's default, a self-signed pair in $TMP/tls): the clients pin its fingerprint.
psk_start_server --duration $((DURATION + 40)) "${SERVER_ARGS[@]}"

# Fetch the assets once so the clients start together.
"$CLIENT" --server 127.0.0.1:$PORT --pin "$PIN" --duration 0.2 --cache "$TMP/cache" >/dev/null
for cap in $CAPS; do
  "$CLIENT" --server 127.0.0.1:$PORT --pin "$PIN" --max-kbps "$cap" --duration "$DURATION" --verify --report json \
    --cache "$TMP/cache" --name "demo-$cap" >"$TMP/client-$cap.json" 2>"$TMP/client-$cap.err" &
  PIDS+=($!)
done
status=0
for i in "${!PIDS[@]}"; do
  ((i == 0)) && continue
  wait "${PIDS[$i]}" || status=1
  PIDS[$i]=""
done

field() { grep -o "\"$2\": [^,}]*" "$1" | head -1 | cut -d' ' -f2; }
echo
echo "progskin streaming demo: default character set, $DURATION s per client, loopback"
grep -h 'bones' "$TMP/server.err" | sed 's/^progskin-server: */  /' || true
printf "%10s  %14s  %13s  %12s  %10s  %10s  %6s\n" "cap kbit/s" "rate kbit/s" "max 1 s kbit/s" "bones/char" "RMS %diag" "max %diag" "loss"
for cap in $CAPS; do
  f=$TMP/client-$cap.json
  if [[ ! -s $f ]]; then printf "%10s  client failed: %s\n" "$cap" "$(tail -1 "$TMP/client-$cap.err")"; status=1; continue; fi
  label=$cap; [[ $cap == 0 ]] && label=unlimited
  printf "%10s  %14.1f  %13.1f  %12.1f  %10.4f  %10.4f  %6.3f\n" "$label" "$(field "$f" rate_kbps)" "$(field "$f" rate_max_kbps)" \
    "$(field "$f" bones_mean)" "$(field "$f" rms_pct)" "$(field "$f" max_pct)" "$(field "$f" loss)"
done
echo
echo "Rate = UDP payload + 28 bytes per datagram (docs/protocol.md); error = displayed vertices vs the"
echo "full-detail reference at the display time (docs/metrics.md §2). More: docs/performance.md, docs/protocol.md,"
echo "progskin-client --help (--view, --report json), progskin-netem --help (slow links)."
exit $status
