#!/usr/bin/env bash
# Configures and builds progskin into build/ (Release-with-debug-info), and
# the browser client into build/web (scripts/build_web.sh) when emscripten is installed.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
cmake -S . -B build -DCMAKE_BUILD_TYPE=RelWithDebInfo >/dev/null
cmake --build build -j"$(nproc)"
# The browser client (WebAssembly + page) into build/web, when emscripten is installed.
if command -v emcmake >/dev/null 2>&1; then
  bash scripts/build_web.sh build
else
  echo "build.sh: emscripten not installed: the browser client (build/web) is not built" >&2
fi
