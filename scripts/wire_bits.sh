#!/usr/bin/env bash
# wire_bits.sh — bits per bone per frame on the wire at full rate (every
# header included: IP/UDP, datagram, chunk, mask, padding, seal), with the
# stream's predicted records and with --standalone-records, one client at
# unlimited rate on loopback against the server's default scene (or the
# server arguments after --). Prints a table row per mode and, with --json
# FILE, the rows as JSON. docs/performance.md "Bits per bone on the wire".
#
#   scripts/wire_bits.sh [--seconds S] [--build DIR] [--json FILE] [-- SERVER ARGS...]
#
# --build: the build directory whose progskin-server / progskin-client run
# (default build; another checkout's build gives a side-by-side figure).
set -euo pipefail
cd "$(dirname "$0")/.."
seconds=8
build=build
json=""
server_args=()
while [ $# -gt 0 ]; do
  case "$1" in
    -h|--help) sed -n '2,12p' "$0" | sed 's/^# \{0,1\}//'; exit 0;;
    --seconds) [ $# -ge 2 ] || { echo "wire_bits.sh: --seconds needs a value" >&2; exit 2; }; seconds=$2; shift 2;;
    --build) [ $# -ge 2 ] || { echo "wire_bits.sh: --build needs a directory" >&2; exit 2; }; build=$2; shift 2;;
    --json) [ $# -ge 2 ] || { echo "wire_bits.sh: --json needs a file" >&2; exit 2; }; json=$2; shift 2;;
    --) shift; server_args=("$@"); break;;
    *) echo "wire_bits.sh: unknown argument $1 (--help)" >&2; exit 2;;
  esac
done
[[ "$seconds" =~ ^[0-9]+$ ]] && [ "$seconds" -ge 2 ] || { echo "wire_bits.sh: --seconds must be a whole number >= 2" >&2; exit 2; }
server="$build/server/progskin-server"
client="$build/client/progskin-client"
for b in "$server" "$client"; do [ -x "$b" ] || { echo "wire_bits.sh: $b not built (bash scripts/build.sh)" >&2; exit 1; }; done
command -v python3 >/dev/null || { echo "wire_bits.sh: needs python3" >&2; exit 1; }
work=$(mktemp -d)
trap 'kill $(jobs -p) 2>/dev/null || true; rm -rf "$work"' EXIT
help=$("$server" --help 2>&1 || true)
if [[ "$help" == *--standalone-records* ]]; then modes=("predicted" "standalone"); else modes=("as built"); fi
rows=()
echo "| mode | rate kbit/s | characters | bones/char | bits per bone per frame | predicted records | missing baselines | RMS % | max % |"
echo "|---|---|---|---|---|---|---|---|---|"
for mode in "${modes[@]}"; do
  port=$(python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1",0)); print(s.getsockname()[1])')
  extra=()
  [ "$mode" = standalone ] && extra=(--standalone-records)
  tag=${mode// /-}
  "$server" --port "$port" --duration $((seconds + 30)) "${extra[@]}" "${server_args[@]}" >"$work/server-$tag.log" 2>&1 &
  srv=$!
  for _ in $(seq 100); do grep -q "listening\|TLS certificate" "$work/server-$tag.log" 2>/dev/null && break; sleep 0.2; done
  sleep 1
  if ! "$client" --server "127.0.0.1:$port" --insecure --duration "$seconds" --warmup 2 --verify --verify-every 3 \
       --report json >"$work/report-$tag.json" 2>"$work/client-$tag.log"; then
    echo "wire_bits.sh: the $mode client failed:" >&2; tail -5 "$work/client-$tag.log" >&2; exit 1
  fi
  kill "$srv" 2>/dev/null || true; wait "$srv" 2>/dev/null || true
  row=$(python3 - "$work/report-$tag.json" "$mode" <<'EOF'
import json, sys
r = json.load(open(sys.argv[1]))
bones = r["characters"] * r["bones_mean"]
bits = r["rate_kbps"] * 1000.0 / 30.0 / bones if bones else float("nan")
row = {"mode": sys.argv[2], "rate_kbps": r["rate_kbps"], "characters": r["characters"], "bones_mean": r["bones_mean"],
       "bits_per_bone": bits, "predicted_records": r.get("predicted_records", 0),
       "missing_baselines": r.get("missing_baselines", 0), "rms_pct": r["rms_pct"], "max_pct": r["max_pct"]}
print(json.dumps(row))
EOF
)
  rows+=("$row")
  python3 -c 'import json,sys; r=json.loads(sys.argv[1]); print("| %s | %.1f | %d | %.2f | %.1f | %d | %d | %.4f | %.3f |" % (r["mode"], r["rate_kbps"], r["characters"], r["bones_mean"], r["bits_per_bone"], r["predicted_records"], r["missing_baselines"], r["rms_pct"], r["max_pct"]))' "$row"
done
if [ -n "$json" ]; then
  (IFS=,; echo "[${rows[*]}]") | python3 -m json.tool >"$json"
fi
