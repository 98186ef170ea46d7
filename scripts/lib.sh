# lib.sh — what the loopback scripts (demo.sh, soak.sh, multiplayer.sh) share:
# a temporary folder and the processes to stop on exit, and starting a
# progskin-server and reading its ports and certificate fingerprint.
# Source it after setting SERVER (the progskin-server binary) and NAME (the
# script's name, for messages).

# TMP: a fresh folder; PIDS: processes killed (and TMP removed) on exit.
TMP=$(mktemp -d)
PIDS=()
psk_cleanup() {
  for p in "${PIDS[@]:-}"; do [[ -n $p ]] && kill "$p" 2>/dev/null || true; done
  wait 2>/dev/null || true
  rm -rf "$TMP"
}
trap psk_cleanup EXIT INT TERM

# psk_start_server ARGS...: starts "$SERVER" --port 0 --tls-dir "$TMP/tls" ARGS
# (stdout in $TMP/server.out), waits for its listening line and sets
# SERVER_PID, PORT (TCP), UDP_PORT and PIN (the sha256 of its self-signed
# certificate, which the clients pin). Exits 1 with the server's stderr when
# it fails.
psk_start_server() {
  "$SERVER" --port 0 --tls-dir "$TMP/tls" "$@" >"$TMP/server.out" 2>"$TMP/server.err" &
  SERVER_PID=$!
  PIDS+=("$SERVER_PID")
  PORT=""
  for _ in $(seq 1 200); do
    PORT=$(grep -o 'TCP [0-9]*' "$TMP/server.out" 2>/dev/null | cut -d' ' -f2 || true)
    [[ -n $PORT ]] && break
    if ! kill -0 "$SERVER_PID" 2>/dev/null; then cat "$TMP/server.err" >&2; echo "$NAME: server failed" >&2; exit 1; fi
    sleep 0.1
  done
  [[ -n $PORT ]] || { echo "$NAME: server did not start" >&2; cat "$TMP/server.err" >&2; exit 1; }
  UDP_PORT=$(grep -o 'UDP [0-9]*' "$TMP/server.out" | cut -d' ' -f2)
  PIN=$(sed -n 's/^progskin-server: TLS certificate sha256 //p' "$TMP/server.out")
  [[ -n $PIN ]] || { echo "$NAME: the server printed no certificate fingerprint" >&2; exit 1; }
}
