#!/usr/bin/env bash
# Builds the browser client (docs/browser.md) into build/web: the client
# session core compiled to WebAssembly with Debian's emscripten (web/CMakeLists.txt,
# configured in build/web-wasm) and the page (index.html, progskin.js,
# three.js from web/node_modules: `npm ci` in web/, scripts/setup.sh does).
# progskin-server --web PORT serves build/web (docs/browser.md).
#   scripts/build_web.sh [BUILD_DIR]     (default build)
set -euo pipefail
cd "$(dirname "$0")/.."
build="${1:-build}"
case "$build" in /*) ;; *) build="$PWD/$build" ;; esac
if [ "${1:-}" = "--help" ] || [ "${1:-}" = "-h" ]; then
  sed -n '2,8p' "$0" | sed 's/^# \{0,1\}//'
  exit 0
fi
command -v emcmake >/dev/null || { echo "build_web.sh: emcmake not found: apt-get install emscripten (scripts/setup.sh)" >&2; exit 1; }
[ -f web/node_modules/three/build/three.module.js ] || { echo "build_web.sh: three.js missing: (cd web && npm ci)" >&2; exit 1; }
# Debian's emscripten runs its JavaScript tools with node and finds acorn in
# /usr/share/nodejs (node-acorn); a node from elsewhere does not look there.
export NODE_PATH="/usr/share/nodejs${NODE_PATH:+:$NODE_PATH}"
# Debian's cache is prebuilt and frozen; a writable copy is only needed if it is not.
if [ ! -w /usr/share/emscripten/cache ] && [ -z "${EM_CACHE:-}" ] && ! grep -q "FROZEN_CACHE = True" /usr/share/emscripten/.emscripten 2>/dev/null; then
  export EM_CACHE="$build/web-wasm/em-cache"
fi
emcmake cmake -S web -B "$build/web-wasm" -DCMAKE_BUILD_TYPE=Release -DPROGSKIN_WEB_OUT="$build/web" >/dev/null
cmake --build "$build/web-wasm" -j"$(nproc)"
echo "build_web.sh: $build/web ($(ls "$build/web" | tr '\n' ' '))"
