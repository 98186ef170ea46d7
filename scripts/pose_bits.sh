#!/usr/bin/env bash
# pose_bits.sh — what a player's published character costs upstream: one
# progskin-client per asset publishes it (walking, its clips) to a
# catalogue-only server on loopback, a second client watches and verifies
# it; prints per asset the Pose rate (every header included: IP/UDP,
# datagram, seal), bits per bone per pose, how many poses were predicted
# from an acknowledged one, and the watcher's RMS of that character.
# docs/performance.md "Published poses upstream".
#
#   scripts/pose_bits.sh [--seconds S] [--build DIR] [--json FILE] [ASSET...]
#
# ASSET: file names of the server's default catalogue (default Fox.glb
# CesiumMan.glb); --build: the build directory whose programs run.
set -euo pipefail
cd "$(dirname "$0")/.."
seconds=8
build=build
json=""
assets=()
need() { [[ $# -ge 2 ]] || { echo "pose_bits.sh: $1 needs a value (--help)" >&2; exit 2; }; }
while (($#)); do
  case "$1" in
    -h|--help) sed -n '2,14p' "$0" | sed 's/^# \{0,1\}//'; exit 0;;
    --seconds) need "$@"; seconds=$2; shift 2;;
    --build) need "$@"; build=$2; shift 2;;
    --json) need "$@"; json=$2; shift 2;;
    -*) echo "pose_bits.sh: unknown argument $1 (--help)" >&2; exit 2;;
    *) assets+=("$1"); shift;;
  esac
done
[ ${#assets[@]} -gt 0 ] || assets=(Fox.glb CesiumMan.glb)
[[ "$seconds" =~ ^[0-9]+$ ]] && [ "$seconds" -ge 3 ] || { echo "pose_bits.sh: --seconds must be a whole number >= 3" >&2; exit 2; }
SERVER="$build/server/progskin-server"
client="$build/client/progskin-client"
for b in "$SERVER" "$client"; do [ -x "$b" ] || { echo "pose_bits.sh: $b not built (bash scripts/build.sh)" >&2; exit 1; }; done
command -v python3 >/dev/null || { echo "pose_bits.sh: needs python3" >&2; exit 1; }
NAME=pose_bits.sh
# shellcheck source=scripts/lib.sh
source scripts/lib.sh
work=$TMP
echo "| asset | bones | poses | predicted | Pose kbit/s | bits per bone per pose | watcher's RMS % |"
echo "|---|---|---|---|---|---|---|"
rows=()
for asset in "${assets[@]}"; do
  psk_start_server --no-scene --duration $((seconds + 30))
  "$client" --server "127.0.0.1:$PORT" --pin "$PIN" --duration "$seconds" --publish "$asset" --walk 1 \
    --report json >"$work/pub.json" 2>"$work/pub.log" &
  pub=$!
  if ! "$client" --server "127.0.0.1:$PORT" --pin "$PIN" --duration "$seconds" --warmup 2 --verify --verify-every 3 \
       --report json >"$work/watch.json" 2>"$work/watch.log"; then
    echo "pose_bits.sh: the watching client failed:" >&2; tail -5 "$work/watch.log" >&2; exit 1
  fi
  wait "$pub" || { echo "pose_bits.sh: the publishing client failed:" >&2; tail -5 "$work/pub.log" >&2; exit 1; }
  kill "$SERVER_PID" 2>/dev/null || true; wait "$SERVER_PID" 2>/dev/null || true
  row=$(python3 - "$work/pub.json" "$work/watch.json" "$asset" <<'EOF'
import json, sys
p = json.load(open(sys.argv[1]))
w = json.load(open(sys.argv[2]))
bones = w["bones_mean"]  # the watcher shows every bone of the one character at full rate
poses_per_s = p["poses_sent"] / max(p["seconds"], 1e-9)
bits = p["pose_kbps"] * 1000.0 / poses_per_s / bones if bones and poses_per_s else float("nan")
row = {"asset": sys.argv[3], "bones": bones, "poses": p["poses_sent"], "predicted": p["poses_predicted"],
       "pose_kbps": p["pose_kbps"], "bits_per_bone": bits, "rms_pct": w["remote"]["rms_pct"]}
print(json.dumps(row))
EOF
)
  rows+=("$row")
  python3 -c 'import json,sys; r=json.loads(sys.argv[1]); print("| %s | %.0f | %d | %d | %.1f | %.1f | %s |" % (r["asset"], r["bones"], r["poses"], r["predicted"], r["pose_kbps"], r["bits_per_bone"], "n/a" if r["rms_pct"] is None else "%.4f" % r["rms_pct"]))' "$row"
done
if [ -n "$json" ]; then
  (IFS=,; echo "[${rows[*]}]") | python3 -m json.tool >"$json"
fi
