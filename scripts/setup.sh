#!/usr/bin/env bash
# Installs the Debian packages progskin builds with, when any is missing.
set -euo pipefail
PKGS=(build-essential cmake pkg-config libasio-dev libflatbuffers-dev flatbuffers-compiler
      libglm-dev libeigen3-dev libtinygltf-dev nlohmann-json3-dev libgtest-dev libbenchmark-dev
      libegl-dev libgl-dev libegl-mesa0 libgl1-mesa-dri libstb-dev gnuplot-nox libsodium-dev libssl-dev
      libhwy-dev mono-mcs mono-runtime libnats-dev nats-server openssl
      emscripten chromium)  # the browser client (scripts/build_web.sh) and its test (docs/browser.md)
missing=()
for p in "${PKGS[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if ((${#missing[@]})); then
  echo "setup: installing ${missing[*]}" >&2
  SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq "${missing[@]}" >/dev/null
fi
# Node.js and npm (the browser client's three.js, its test, the glTF
# validator): Debian's, unless a node is already installed (another
# distribution of it, e.g. NodeSource's, conflicts with Debian's npm package).
if ! command -v node >/dev/null 2>&1 || ! command -v npm >/dev/null 2>&1; then
  echo "setup: installing nodejs npm" >&2
  SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq nodejs npm >/dev/null
fi
# The Khronos glTF validator for tests/test_gltf_validator.cpp (npm, pinned in
# scripts/gltf_validator/package.json); the test skips, saying so, without it.
validator_dir="$(cd "$(dirname "$0")" && pwd)/gltf_validator"
if command -v npm >/dev/null 2>&1 && [ ! -d "$validator_dir/node_modules/gltf-validator" ]; then
  echo "setup: installing the glTF validator (npm ci in scripts/gltf_validator)" >&2
  (cd "$validator_dir" && npm ci --no-audit --no-fund >/dev/null 2>&1) ||
    echo "setup: npm ci failed (offline?); tests/test_gltf_validator.cpp will be skipped" >&2
fi
# The browser client's npm packages (web/package.json: three.js for the page,
# puppeteer-core for tests/browser, which drives Debian's chromium; no browser
# is downloaded).
web_dir="$(cd "$(dirname "$0")/.." && pwd)/web"
if command -v npm >/dev/null 2>&1 && { [ ! -d "$web_dir/node_modules/three" ] || [ ! -d "$web_dir/node_modules/puppeteer-core" ]; }; then
  echo "setup: installing the browser client's npm packages (npm ci in web)" >&2
  (cd "$web_dir" && PUPPETEER_SKIP_DOWNLOAD=1 npm ci --no-audit --no-fund >/dev/null 2>&1) ||
    echo "setup: npm ci in web failed (offline?); the browser client cannot be built" >&2
fi
