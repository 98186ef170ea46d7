#!/usr/bin/env bash
# loss_error.sh — displayed error under loss against the lossless error at the
# same rate cap (issue 27: at 10 % loss with reordering and duplication, no
# displayed frame decodes from a baseline the client did not have, and the
# RMS stays within 1.5 x the lossless RMS). For each cap one server (default
# scene, or the server arguments after --) streams to one client through a
# progskin-netem relay three times: a clean link (--delay-ms/--jitter-ms
# only), a bad one (the same plus --loss, --reorder, --duplicate), and the
# clean link again capped at the rate the bad one delivered (the rate
# controller backs off on loss), each a progskin-client --verify --report
# json. Prints a table row per cap and link ("relay": both directions, the
# bad link's drops server -> client only; "loss seen": the sequence numbers
# the client never received, after the server's repairs, so near 0 where the
# stream has room for repairs), the ratios RMS(bad) / RMS(clean)
# at the same cap and at the same rate, and with --json FILE the rows as JSON.
# docs/performance.md "Four humanoids", "Error under loss".
#
#   scripts/loss_error.sh [--caps "64 0"] [--seconds S] [--loss P] [--reorder P] [--duplicate P]
#                         [--delay-ms N] [--jitter-ms N] [--seed N] [--build DIR] [--json FILE]
#                         [-- SERVER ARGS...]
#
# --caps: client --max-kbps values, 0 = unlimited (default "64 0"); --seconds:
# each client's streaming time (default 10, the first 2 s left out of the
# error as warm-up); --loss/--reorder/--duplicate: the bad link's
# probabilities (default 0.1 each); --delay-ms/--jitter-ms: both links
# (default 10 and 5, as tests/test_net_bandwidth.cpp's lossy-link test);
# --build: the build directory with server/progskin-server,
# server/progskin-netem and client/progskin-client (default build).
# Exit status: 0 when every client ran (whatever the figures), 1 when one
# failed, 2 bad arguments.
set -euo pipefail
cd "$(dirname "$0")/.."
BUILD=build
CAPS="64 0"
RUN_SECONDS=10
LOSS=0.1
REORDER=0.1
DUPLICATE=0.1
DELAY=10
JITTER=5
SEED=1
JSON=""
SERVER_ARGS=()
need() { [[ $# -ge 2 ]] || { echo "loss_error.sh: $1 needs a value (--help)" >&2; exit 2; }; }
while (($#)); do
  case "$1" in
    -h|--help) sed -n '2,30p' "$0" | sed 's/^# \{0,1\}//'; exit 0;;
    --caps) need "$@"; CAPS=$2; shift 2;;
    --seconds) need "$@"; RUN_SECONDS=$2; shift 2;;
    --loss) need "$@"; LOSS=$2; shift 2;;
    --reorder) need "$@"; REORDER=$2; shift 2;;
    --duplicate) need "$@"; DUPLICATE=$2; shift 2;;
    --delay-ms) need "$@"; DELAY=$2; shift 2;;
    --jitter-ms) need "$@"; JITTER=$2; shift 2;;
    --seed) need "$@"; SEED=$2; shift 2;;
    --build) need "$@"; BUILD=$2; shift 2;;
    --json) need "$@"; JSON=$2; shift 2;;
    --) shift; SERVER_ARGS=("$@"); break;;
    *) echo "loss_error.sh: unknown argument $1 (--help)" >&2; exit 2;;
  esac
done
if ! [[ $RUN_SECONDS =~ ^[0-9]+$ ]] || ((RUN_SECONDS < 4)); then
  echo "loss_error.sh: --seconds must be a whole number >= 4" >&2; exit 2
fi
[[ -n ${CAPS// /} ]] || { echo "loss_error.sh: --caps is empty" >&2; exit 2; }
for c in $CAPS; do [[ $c =~ ^[0-9]+$ ]] || { echo "loss_error.sh: --caps takes whole kbit/s values (0 = unlimited), not $c" >&2; exit 2; }; done
for p in "$LOSS" "$REORDER" "$DUPLICATE"; do
  [[ $p =~ ^(0(\.[0-9]+)?|1(\.0*)?|\.[0-9]+)$ ]] || { echo "loss_error.sh: --loss, --reorder and --duplicate are probabilities (0..1), not $p" >&2; exit 2; }
done
for n in "$DELAY" "$JITTER" "$SEED"; do
  [[ $n =~ ^[0-9]+$ ]] || { echo "loss_error.sh: --delay-ms, --jitter-ms and --seed take whole numbers, not $n" >&2; exit 2; }
done
SERVER=$BUILD/server/progskin-server
CLIENT=$BUILD/client/progskin-client
NETEM=$BUILD/server/progskin-netem
for b in "$SERVER" "$CLIENT" "$NETEM"; do
  [[ -x $b ]] || { echo "loss_error.sh: $b not built (bash scripts/build.sh)" >&2; exit 1; }
done
command -v python3 >/dev/null || { echo "loss_error.sh: needs python3" >&2; exit 1; }

NAME=loss_error.sh
# shellcheck source=scripts/lib.sh
source scripts/lib.sh

# One server for every run (TLS and sealed datagrams: the programs' defaults;
# the relay forwards sealed datagrams, the client drops duplicates as replays).
psk_start_server "${SERVER_ARGS[@]}"
"$CLIENT" --server 127.0.0.1:"$PORT" --pin "$PIN" --duration 0.2 --cache "$TMP/cache" >/dev/null 2>"$TMP/fetch.err" || {
  echo "loss_error.sh: the first client (asset download) failed:" >&2; tail -5 "$TMP/fetch.err" >&2; exit 1; }

# run CAP LINK: one client through a fresh relay; its report in $TMP/CAP-LINK.json,
# the relay's counts in $TMP/CAP-LINK.netem.
run() {
  local cap=$1 link=$2 limit=${3:-$1} impair=()
  [[ $link == bad ]] && impair=(--loss "$LOSS" --reorder "$REORDER" --duplicate "$DUPLICATE")
  "$NETEM" --to 127.0.0.1:"$UDP_PORT" --listen 0 --delay-ms "$DELAY" --jitter-ms "$JITTER" --seed "$SEED" "${impair[@]}" \
    >"$TMP/$cap-$link.netem.out" 2>"$TMP/$cap-$link.netem" &
  local netem=$! relay=""
  PIDS+=("$netem")
  for _ in $(seq 1 100); do
    relay=$(grep -o 'UDP [0-9.]*:[0-9]*' "$TMP/$cap-$link.netem.out" 2>/dev/null | head -1 | grep -o '[0-9]*$' || true)
    [[ -n $relay ]] && break
    sleep 0.1
  done
  [[ -n $relay ]] || { echo "loss_error.sh: progskin-netem did not start:" >&2; cat "$TMP/$cap-$link.netem" >&2; exit 1; }
  local max=()
  ((limit > 0)) && max=(--max-kbps "$limit")
  if ! "$CLIENT" --server 127.0.0.1:"$PORT" --pin "$PIN" --udp-via 127.0.0.1:"$relay" "${max[@]}" \
       --duration "$RUN_SECONDS" --warmup 2 --verify --verify-every 3 --report json --cache "$TMP/cache" \
       >"$TMP/$cap-$link.json" 2>"$TMP/$cap-$link.err"; then
    echo "loss_error.sh: the client (cap $cap, $link link) failed:" >&2; tail -5 "$TMP/$cap-$link.err" >&2; exit 1
  fi
  kill -TERM "$netem" 2>/dev/null || true
  wait "$netem" 2>/dev/null || true
}

echo "link: delay ${DELAY} ms, jitter ${JITTER} ms; bad: loss $LOSS, reorder $REORDER, duplicate $DUPLICATE (progskin-netem, seed $SEED); ${RUN_SECONDS} s per client"
for cap in $CAPS; do
  run "$cap" clean
  run "$cap" bad
  # The clean link again, capped at the rate the bad link delivered: the
  # rate controller backs off on loss, so "the same cap" is not "the same
  # rate"; this isolates what the loss itself costs the display.
  # (The pacer fills at 94 % of a cap: the cap is the delivered rate / 0.94.)
  rate=$(python3 -c 'import json,sys; print(max(1, round(json.load(open(sys.argv[1]))["rate_kbps"] / 0.94)))' "$TMP/$cap-bad.json")
  run "$cap" clean-at-rate "$rate"
done

# shellcheck disable=SC2086  # one argument per cap
python3 - "$TMP" "$JSON" $CAPS <<'EOF'
import json, re, sys
tmp, out, caps = sys.argv[1], sys.argv[2], sys.argv[3:]
rows = []
print("| cap kbit/s | link | rate kbit/s | relay: forwarded / dropped / reordered / duplicated | loss seen (after repairs) | RMS % | max % "
      "| predicted records | missing baselines | RMS bad / clean | RMS bad / clean at its rate |")
print("|---|---|---|---|---|---|---|---|---|---|---|")
for cap in caps:
    clean = bad = None
    for link in ("clean", "bad", "clean-at-rate"):
        r = json.load(open("%s/%s-%s.json" % (tmp, cap, link)))
        stats = open("%s/%s-%s.netem" % (tmp, cap, link)).read()
        m = re.search(r"forwarded (\d+), dropped (\d+), queue drops (\d+), duplicated (\d+), reordered (\d+)", stats)
        fwd, drop, qdrop, dup, reo = (int(x) for x in m.groups()) if m else (0, 0, 0, 0, 0)
        row = {"cap_kbps": int(cap), "link": link, "rate_kbps": r["rate_kbps"], "characters": r["characters"],
               "bones_mean": r["bones_mean"], "relay_forwarded": fwd, "relay_dropped": drop, "relay_duplicated": dup,
               "relay_reordered": reo, "loss": r.get("loss", 0.0), "rms_pct": r["rms_pct"], "max_pct": r["max_pct"],
               "predicted_records": r.get("predicted_records", 0), "missing_baselines": r.get("missing_baselines", 0)}
        if link == "clean":
            clean = row
        elif link == "bad":
            bad = row
            row["rms_ratio"] = row["rms_pct"] / clean["rms_pct"] if clean["rms_pct"] > 0 else float("nan")
        else:
            bad["rms_ratio_same_rate"] = bad["rms_pct"] / row["rms_pct"] if row["rms_pct"] > 0 else float("nan")
        rows.append(row)
    for row in rows[-3:]:
        print("| %s | %s | %.1f | %d / %d / %d / %d | %.3f | %.4f | %.3f | %d | %d | %s | %s |" % (
            cap if cap != "0" else "unlimited", row["link"], row["rate_kbps"], row["relay_forwarded"], row["relay_dropped"],
            row["relay_reordered"], row["relay_duplicated"], row["loss"], row["rms_pct"],
            row["max_pct"], row["predicted_records"], row["missing_baselines"],
            "%.2f" % row["rms_ratio"] if "rms_ratio" in row else "-",
            "%.2f" % row["rms_ratio_same_rate"] if "rms_ratio_same_rate" in row else "-"))
if out:
    with open(out, "w") as f:
        json.dump(rows, f, indent=1)
        f.write("\n")
EOF
