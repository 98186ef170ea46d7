#!/usr/bin/env bash
# soak.sh — a long run on loopback (not part of CI): one progskin-server, N
# honest clients (default 30) streaming for M minutes (default 10), half of
# them through progskin-netem at 10 % loss, 5 % reordering, 2 % duplication
# (5 ms jitter), beside an attacker mix (progskin-attack, tests/attack_main.cpp:
# sessions posing the most characters they may with Views of 4,096 weights,
# churn, stalled TLS handshakes, squatters, asset pulls; from 127.0.0.2..5).
# Reports the server's memory growth (resident set after the first fifth of
# the run -> end; target < 5 %), whether the server crashed, each client's
# exit code, mean rate against its cap and longest gap between frames, the
# server's refusals by reason and what the attacker did.
#
#   scripts/soak.sh [--minutes M | --seconds S] [--clients N] [--cap KBPS] [--no-attack]
#                   [--attack-args "ARGS"] [--server-args "ARGS"] [--build DIR]
#
# --attack-args overrides arguments of the attacker mix (progskin-attack --help),
# --server-args adds progskin-server arguments (e.g. --crowd 1000): one case
# of docs/performance.md "Hardening" at a time.
# Exit status: 0 when every honest client exited 0, the server survived and
# its memory grew less than 5 %; 1 otherwise. Stops every process it started.
set -euo pipefail
cd "$(dirname "$0")/.."
BUILD=${PROGSKIN_BUILD:-build}
MINUTES=10
CLIENTS=30
CAP=256
ATTACK=1
ATTACK_ARGS=""
SERVER_ARGS=""
RUN_SECONDS=""
while (($#)); do
  case "$1" in
    --minutes) MINUTES=$2; shift 2;;
    --seconds) RUN_SECONDS=$2; shift 2;;
    --no-attack) ATTACK=0; shift;;
    --attack-args) ATTACK_ARGS=$2; shift 2;;
    --server-args) SERVER_ARGS=$2; shift 2;;
    --clients) CLIENTS=$2; shift 2;;
    --cap) CAP=$2; shift 2;;
    --build) BUILD=$2; shift 2;;
    -h|--help) sed -n '2,22p' "$0" | sed 's/^# \{0,1\}//'; exit 0;;
    *) echo "soak.sh: unknown argument $1" >&2; exit 2;;
  esac
done
[[ $MINUTES =~ ^[0-9]+([.][0-9]+)?$ ]] || { echo "soak.sh: --minutes takes a number, not $MINUTES" >&2; exit 2; }
SECONDS_RUN=$(awk -v m="$MINUTES" 'BEGIN { printf "%d", m * 60 }')
if [[ -n $RUN_SECONDS ]]; then
  [[ $RUN_SECONDS =~ ^[0-9]+$ ]] || { echo "soak.sh: --seconds takes a whole number, not $RUN_SECONDS" >&2; exit 2; }
  SECONDS_RUN=$RUN_SECONDS
fi
((SECONDS_RUN >= 10)) || { echo "soak.sh: the run is too short (at least 10 s)" >&2; exit 2; }

SERVER=$BUILD/server/progskin-server
CLIENT=$BUILD/client/progskin-client
NETEM=$BUILD/server/progskin-netem
ATTACKER=$BUILD/tests/progskin-attack
BINS=("$SERVER" "$CLIENT" "$NETEM")
((ATTACK)) && BINS+=("$ATTACKER")
for b in "${BINS[@]}"; do
  [[ -x $b ]] || { echo "soak.sh: $b missing (cmake --build $BUILD --target progskin-server progskin-client progskin-netem progskin-attack)" >&2; exit 2; }
done

NAME=soak.sh
# shellcheck source=scripts/lib.sh
source scripts/lib.sh

wait_port() {  # file, pattern -> port
  local port=""
  for _ in $(seq 1 200); do
    port=$(grep -o "$2 [0-9.]*:*[0-9]*" "$1" 2>/dev/null | head -1 | grep -o '[0-9]*$' || true)
    [[ -n $port ]] && { echo "$port"; return 0; }
    sleep 0.1
  done
  return 1
}

# TLS and sealed datagrams (the server's defaults; netem relays sealed datagrams,
# its duplicates are dropped as replays): the clients pin the certificate.
# Room for the attacker's sessions too: a full server evicts by address, and
# every honest client here shares 127.0.0.1 (the eviction rules are the
# hardening tests' business, not the soak's).
# shellcheck disable=SC2086  # --server-args is split into arguments on purpose
psk_start_server --max-clients $((CLIENTS + 64)) $SERVER_ARGS
"$NETEM" --to 127.0.0.1:"$UDP_PORT" --listen 0 --loss 0.1 --reorder 0.05 --duplicate 0.02 --jitter-ms 5 \
  >"$TMP/netem.out" 2>"$TMP/netem.err" &
NETEM_PID=$!
PIDS+=("$NETEM_PID")
NETEM_PORT=$(wait_port "$TMP/netem.out" "UDP") || { echo "soak.sh: netem did not start" >&2; exit 1; }

"$CLIENT" --server 127.0.0.1:"$PORT" --pin "$PIN" --duration 0.2 --cache "$TMP/cache" >/dev/null  # assets once
rss() { awk '/^VmRSS:/ { print $2 }' "/proc/$SERVER_PID/status" 2>/dev/null || echo 0; }

CPIDS=()
for i in $(seq 1 "$CLIENTS"); do
  via=()
  ((i % 2 == 0)) && via=(--udp-via 127.0.0.1:"$NETEM_PORT")
  "$CLIENT" --server 127.0.0.1:"$PORT" --pin "$PIN" "${via[@]}" --max-kbps "$CAP" --duration "$SECONDS_RUN" --report json \
    --cache "$TMP/cache" --name "soak-$i" >"$TMP/client-$i.json" 2>"$TMP/client-$i.err" &
  CPIDS+=($!)
  PIDS+=($!)
done

# The attacker, once the honest clients are streaming, until shortly before they stop.
if ((ATTACK)); then
  sleep 3
  # shellcheck disable=SC2086
  "$ATTACKER" --server 127.0.0.1:"$PORT" --duration $((SECONDS_RUN - 5)) $ATTACK_ARGS >"$TMP/attack.json" 2>"$TMP/attack.err" &
  ATTACK_PID=$!
  PIDS+=("$ATTACK_PID")
fi

# Memory: resident set every 5 s; the baseline is taken after a fifth of the run.
start=$(date +%s)
base=""
peak=0
: >"$TMP/rss"
while :; do
  now=$(date +%s)
  el=$((now - start))
  alive=0
  for p in "${CPIDS[@]}"; do kill -0 "$p" 2>/dev/null && alive=1 && break; done
  ((alive)) || break
  kill -0 "$SERVER_PID" 2>/dev/null || break
  r=$(rss)
  echo "$el $r" >>"$TMP/rss"
  ((r > peak)) && peak=$r
  [[ -z $base ]] && ((el * 5 >= SECONDS_RUN)) && base=$r
  sleep 5
done
end_rss=$(rss)
# The server's CPU time (user + system) over the run, in seconds.
cpu=$(awk -v hz="$(getconf CLK_TCK)" '{ printf "%.1f", ($14 + $15) / hz }' "/proc/$SERVER_PID/stat" 2>/dev/null || echo "?")

status=0
codes=()
for i in "${!CPIDS[@]}"; do
  rc=0
  wait "${CPIDS[$i]}" || rc=$?
  codes+=("$rc")
  ((rc == 0)) || status=1
done
crashed=0
if kill -0 "$SERVER_PID" 2>/dev/null; then
  kill -TERM "$SERVER_PID"
  rc=0; wait "$SERVER_PID" || rc=$?
  ((rc == 0)) || { crashed=1; echo "soak.sh: server exited $rc on SIGTERM" >&2; }
else
  crashed=1
  wait "$SERVER_PID" || true
fi
kill "$NETEM_PID" 2>/dev/null || true
wait "$NETEM_PID" 2>/dev/null || true
if ((ATTACK)); then
  kill "$ATTACK_PID" 2>/dev/null || true
  wait "$ATTACK_PID" 2>/dev/null || true
fi
PIDS=()
((crashed)) && status=1

field() { grep -o "\"$2\": [^,}]*" "$1" | head -1 | cut -d' ' -f2; }
echo "soak: $CLIENTS clients x ${SECONDS_RUN} s, cap $CAP kbit/s, even-numbered clients via netem (10 % loss, 5 % reorder, 2 % duplication)$( ((ATTACK)) && echo ", beside progskin-attack")"
[[ -z $base ]] && base=$(head -1 "$TMP/rss" | cut -d' ' -f2)
growth=$(awk -v a="${base:-0}" -v b="${end_rss:-0}" 'BEGIN { if (a > 0) printf "%.1f", 100 * (b - a) / a; else print "n/a" }')
echo "server: crashed=$crashed, RSS ${base:-?} KiB after $((SECONDS_RUN / 5)) s -> ${end_rss:-?} KiB at end (${growth} %), peak $peak KiB, CPU $cpu s"
awk -v g="$growth" 'BEGIN { exit !(g != "n/a" && g + 0 >= 5) }' && { echo "soak: memory grew 5 % or more" >&2; status=1; }
((ATTACK)) && echo "attacker: $(cat "$TMP/attack.json" 2>/dev/null || echo 'no report') $(tail -1 "$TMP/attack.err" 2>/dev/null)"
grep -h "refusals:" "$TMP/server.err" | tail -1 | sed 's/^progskin-server: /server /'
printf "%-8s %-6s %5s %12s %9s %8s %10s %8s\n" client path exit "rate kbit/s" "of cap" loss "bones/char" "gap ms"
for i in $(seq 1 "$CLIENTS"); do
  f=$TMP/client-$i.json
  path=direct; ((i % 2 == 0)) && path=netem
  if [[ ! -s $f ]]; then
    printf "%-8s %-6s %5s  %s\n" "soak-$i" "$path" "${codes[$((i - 1))]}" "$(tail -1 "$TMP/client-$i.err")"
    continue
  fi
  r=$(field "$f" rate_kbps)
  printf "%-8s %-6s %5s %12.1f %8.0f%% %7.1f%% %10.1f %8.0f\n" "soak-$i" "$path" "${codes[$((i - 1))]}" "$r" \
    "$(awk -v r="$r" -v c="$CAP" 'BEGIN { print 100 * r / c }')" "$(awk -v l="$(field "$f" loss)" 'BEGIN { print 100 * l }')" \
    "$(field "$f" bones_mean)" "$(field "$f" max_gap_ms)"
done | tee "$TMP/table"
for path in direct netem; do
  awk -v p="$path" -v c="$CAP" '$2 == p && NF >= 7 { n++; s += $4; if (min == "" || $4 < min) min = $4; if ($4 > max) max = $4 }
    END { if (n) printf "%s: %d clients, rate mean %.1f min %.1f max %.1f kbit/s (cap %s)\n", p, n, s / n, min, max, c }' "$TMP/table"
  awk -v p="$path" '$2 == p && NF >= 8 { if ($8 > g) g = $8 } END { if (g != "") printf "%s: longest gap between frames %.0f ms\n", p, g }' "$TMP/table"
done
exit $status
