#!/usr/bin/env bash
# cluster.sh — a world of progskin-server nodes on loopback (issue 26 item 5):
# starts nats-server on a free port and N catalogue-only nodes joined to it
# (progskin-server --nats nats://127.0.0.1:PORT --node nK --world W --no-scene,
# TLS with one self-signed pair that every node shares, --stats-every 1), runs
# progskin-loadgen across them (players round-robin over the nodes), then
# prints a table: the loadgen's figures (rate, bones, latency same-node and
# cross-node, starved, errors) and each node's cost over the measurement
# window (mean of its --stats-every lines while the loadgen measured: mean
# tick, process CPU, datagrams and kbit/s sent, world bus messages and bytes
# per second each way). Every process is stopped on exit (trap).
# With --nodes 1 (no --nats), the same against one node.
#
#   scripts/cluster.sh [--nodes N] [--players N] [--duration S] [--max-kbps K]
#                      [--delay-ms D] [--threads T] [--asset NAME|INDEX]
#                      [--walk R] [--spacing D] [--see K] [--connect-rate N]
#                      [--placement round-robin|bands] [--loadgen-threads T]
#                      [--server-args "ARGS"] [--json FILE] [--build DIR]
#                      [--nats-tls]
# --threads: each node's tick threads; --loadgen-threads: the loadgen's
# threads (default 1).
# --server-args: more progskin-server options for every node (e.g.
# "--owner-share-kbps 0 --threads 2").
# --nats-tls: the bus over TLS (a self-signed pair made with openssl in the
# run's folder; nats-server --tls, the nodes tls:// with --nats-ca).
#
# Exit status: the loadgen's (0: every player joined and streamed to the end).
set -euo pipefail
cd "$(dirname "$0")/.."
BUILD=${PROGSKIN_BUILD:-build}
NODES=3
PLAYERS=60
DURATION=10
KBPS=256
DELAY=100
THREADS=""
ASSET=CesiumMan.glb
LGOPTS=()
SERVER_ARGS=()
JSON=""
NATS_TLS=0
while (($#)); do
  case "$1" in
    --nodes) NODES=$2; shift 2;;
    --players) PLAYERS=$2; shift 2;;
    --duration) DURATION=$2; shift 2;;
    --max-kbps) KBPS=$2; shift 2;;
    --delay-ms) DELAY=$2; shift 2;;
    --threads) THREADS=$2; shift 2;;
    --asset) ASSET=$2; shift 2;;
    --walk|--spacing|--see|--connect-rate|--settle|--placement) LGOPTS+=("$1" "$2"); shift 2;;
    --loadgen-threads) LGOPTS+=(--threads "$2"); shift 2;;
    --json) JSON=$2; shift 2;;
    --server-args) read -r -a SERVER_ARGS <<<"$2"; shift 2;;
    --build) BUILD=$2; shift 2;;
    --nats-tls) NATS_TLS=1; shift;;
    -h|--help) sed -n '2,25p' "$0" | sed 's/^# \{0,1\}//'; exit 0;;
    *) echo "cluster.sh: unknown argument $1" >&2; exit 2;;
  esac
done
[[ $NODES =~ ^[0-9]+$ ]] && ((NODES >= 1 && NODES <= 16)) || { echo "cluster.sh: --nodes must be 1..16" >&2; exit 2; }
[[ $PLAYERS =~ ^[0-9]+$ ]] && ((PLAYERS >= 1 && PLAYERS <= 4000)) || { echo "cluster.sh: --players must be 1..4000" >&2; exit 2; }
[[ $DURATION =~ ^[0-9]+$ ]] && ((DURATION >= 1 && DURATION <= 3600)) || { echo "cluster.sh: --duration must be 1..3600 (whole seconds)" >&2; exit 2; }
SERVER=$BUILD/server/progskin-server
LOADGEN=$BUILD/tools/progskin-loadgen
[[ -x $SERVER && -x $LOADGEN ]] || { echo "cluster.sh: build progskin-server and progskin-loadgen first" >&2; exit 1; }
if ((NODES > 1)); then
  command -v nats-server >/dev/null || { echo "cluster.sh: nats-server is not installed (apt-get install nats-server)" >&2; exit 1; }
fi

NAME=cluster.sh
# shellcheck source=scripts/lib.sh
source scripts/lib.sh

free_port() { python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1",0)); print(s.getsockname()[1])'; }

NATSOPT=()
if ((NODES > 1)); then
  NATS_PORT=$(free_port)
  NATS_TLSOPT=()
  SCHEME=nats
  if ((NATS_TLS)); then
    command -v openssl >/dev/null || { echo "cluster.sh: --nats-tls needs openssl (apt-get install openssl)" >&2; exit 1; }
    openssl req -x509 -newkey ec -pkeyopt ec_paramgen_curve:P-256 -nodes -days 2 -subj /CN=bus \
      -addext "subjectAltName=IP:127.0.0.1" -keyout "$TMP/bus-key.pem" -out "$TMP/bus.pem" >/dev/null 2>&1
    NATS_TLSOPT=(--tls --tlscert "$TMP/bus.pem" --tlskey "$TMP/bus-key.pem")
    SCHEME=tls
  fi
  nats-server -a 127.0.0.1 -p "$NATS_PORT" "${NATS_TLSOPT[@]}" >"$TMP/nats.log" 2>&1 &
  PIDS+=($!)
  for _ in $(seq 1 100); do (echo >/dev/tcp/127.0.0.1/"$NATS_PORT") 2>/dev/null && break; sleep 0.05; done
  NATSOPT=(--nats "$SCHEME://127.0.0.1:$NATS_PORT" --world "cluster$$")
  ((NATS_TLS)) && NATSOPT+=(--nats-ca "$TMP/bus.pem")
fi

THREADOPT=()
[[ -n $THREADS ]] && THREADOPT=(--threads "$THREADS")
SERVERS=""
NODE_PIDS=()
for k in $(seq 1 "$NODES"); do
  NODEOPT=()
  ((NODES > 1)) && NODEOPT=(--node "n$k")
  # Every node shares the TLS pair of $TMP/tls (one pin for all); room for every player.
  psk_start_server --no-scene --max-clients $((PLAYERS + 16)) --stats-every 1 "${NATSOPT[@]}" "${NODEOPT[@]}" "${THREADOPT[@]}" \
    "${SERVER_ARGS[@]}"
  mv "$TMP/server.out" "$TMP/node$k.out"
  mv "$TMP/server.err" "$TMP/node$k.err"
  NODE_PIDS+=("$SERVER_PID")
  SERVERS+="${SERVERS:+,}127.0.0.1:$PORT"
  # the stats lines go on in the renamed file (the descriptor stays open)
done

echo "cluster.sh: $NODES node(s) at $SERVERS${NATS_PORT:+, nats-server on 127.0.0.1:$NATS_PORT}; $PLAYERS players; load $(cut -d' ' -f1-3 /proc/loadavg)" >&2
set +e
"$LOADGEN" --server "$SERVERS" --pin "$PIN" --players "$PLAYERS" --duration "$DURATION" --max-kbps "$KBPS" --delay-ms "$DELAY" \
  --asset "$ASSET" --cache "$TMP/cache" --report json "${LGOPTS[@]}" >"$TMP/loadgen.json" 2>"$TMP/loadgen.err" &
LG=$!
PIDS+=($LG)
# The window: from the loadgen's "measuring" line to its end; the nodes' stats lines in it.
wait $LG
RC=$?
set -e
cat "$TMP/loadgen.err" >&2
[[ -n $JSON ]] && cp "$TMP/loadgen.json" "$JSON"
for p in "${NODE_PIDS[@]}"; do kill -TERM "$p" 2>/dev/null || true; done
for p in "${NODE_PIDS[@]}"; do wait "$p" 2>/dev/null || true; done

# Node cost over the loadgen's measurement window: the stats lines of the
# last DURATION seconds before the loadgen ended (its window ends it).
python3 - "$TMP" "$NODES" "$DURATION" "$TMP/loadgen.json" <<'EOF'
import json, re, sys
tmp, nodes, duration, lg = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), sys.argv[4]
try:
    r = json.load(open(lg))
except Exception as e:
    print(f"cluster.sh: no loadgen report ({e})", file=sys.stderr); sys.exit(0)
L = r["latency_ms"]
print(f"players {r['players']} on {r['nodes']} node(s) ({r.get('placement', '')}, {r.get('grid_step', 0):.2f} units apart): {r['joined']} joined, {r['failed']} failed; window {r['window_seconds']:.1f} s")
print(f"{'rate kbit/s mean/min/max':34s} {r['rate_kbps']['mean']:8.1f} {r['rate_kbps']['min']:8.1f} {r['rate_kbps']['max']:8.1f}")
print(f"{'bones per chunk / nearest mean':34s} {r['bones']['mean']:8.1f} {r['bones']['nearest_mean']:8.1f}")
print(f"{'nearest seen min/mean of':34s} {r['nearest']['seen_min']:8d} {r['nearest']['seen_mean']:8.1f} {r['nearest']['see']:8d}")
for k in ("receipt", "display", "cross_node_receipt", "cross_node_display"):
    print(f"{(k.replace('_', ' ') + ' ms p50/p99/max'):34s} {L[k]['p50']:8.1f} {L[k]['p99']:8.1f} {L[k]['max']:8.1f}  ({L[k]['samples']} samples)")
s = r["starved"]
print(f"{'starved players / pairs of':34s} {s['players']:8d} {s['pairs']:8d} {s['of_pairs']:8d}  (longest gap {s['max_gap_ms']:.0f} ms)")
print(f"{'loadgen CPU share / late / us per turn':34s} {r['loadgen']['cpu_share']:8.2f} {r['loadgen']['late_turns']:8.3f} {r['loadgen'].get('cpu_us_per_turn', 0):8.1f}")
if r["error"]:
    print(f"error: {r['error']}")
keys = ["sessions", "ticks_per_s", "mean_tick_ms", "cpu_share", "datagrams_per_s", "sent_kbps", "poses_per_s", "world_out_msgs_per_s",
        "world_out_bytes_per_s", "world_in_msgs_per_s", "world_in_bytes_per_s", "world_dropped"]
print(f"{'node':6s}" + "".join(f"{k:>22s}" for k in keys))
for k in range(1, nodes + 1):
    lines = [l for l in open(f"{tmp}/node{k}.err") if "progskin-server: stats " in l]
    # the loadgen's window: its last DURATION lines before the loadgen closed (the last line or two are after)
    rows = []
    for l in lines:
        d = dict(re.findall(r"(\w+)=([-\d.]+)", l))
        rows.append({x: float(d.get(x, 0)) for x in keys})
    peak = max((x["sessions"] for x in rows), default=0)
    full = [x for x in rows if x["sessions"] == peak]
    win = full[-duration - 1:-1] if len(full) > duration else full
    if not win:
        print(f"n{k:<5d} (no stats)"); continue
    mean = {x: sum(w[x] for w in win) / len(win) for x in keys}
    print(f"n{k:<5d}" + "".join(f"{mean[x]:22.2f}" for x in keys))
EOF
for k in $(seq 1 "$NODES"); do
  sed -n 's/^progskin-server: \(refusals:.*\)/n'"$k"' \1/p; s/^progskin-server: \(world bus:.*\)/n'"$k"' \1/p' "$TMP/node$k.err"
done
exit $RC
