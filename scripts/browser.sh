#!/usr/bin/env bash
# The browser client in one command (docs/browser.md): builds progskin and the
# page (scripts/build.sh: the WebAssembly client into build/web), then runs
# progskin-server --no-tls --web PORT serving the page and its WebSocket
# endpoint; open http://HOST:PORT/ in a browser (add ?max_kbps=N for a cap).
#   scripts/browser.sh [PORT] [server options...]     (default 8080)
set -euo pipefail
cd "$(dirname "$0")/.."
if [ "${1:-}" = "--help" ] || [ "${1:-}" = "-h" ]; then
  sed -n '2,6p' "$0" | sed 's/^# \{0,1\}//'
  exit 0
fi
port="${1:-8080}"
shift || true
case "$port" in ''|*[!0-9]*) echo "browser.sh: PORT must be a number (--help)" >&2; exit 2 ;; esac
if [ ! -x build/server/progskin-server ] || [ ! -f build/web/progskin_wasm.wasm ]; then
  bash scripts/build.sh
fi
[ -f build/web/progskin_wasm.wasm ] || { echo "browser.sh: the page was not built (emscripten missing?)" >&2; exit 1; }
echo "browser.sh: open http://127.0.0.1:$port/ (Ctrl-C stops the server)"
exec build/server/progskin-server --no-tls --web "$port" --web-root build/web "$@"
