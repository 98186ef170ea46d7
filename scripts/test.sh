#!/usr/bin/env bash
# Builds progskin and runs every test (the README's test command; CI runs this),
# then installs the package and builds examples/ out of tree against it, as a
# game would (find_package(progskin), progskin::client, progskin::c), runs
# the C example against a server on loopback, and compiles tests/install
# against it.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/build.sh
# PROGSKIN_REQUIRE_BROWSER: Browser.Loopback fails rather than skips when
# chromium or the page (build/web) is missing.
PROGSKIN_REQUIRE_BROWSER=1 ctest --test-dir build --output-on-failure -j"$(nproc)"
rm -rf build/install build/example-out-of-tree build/install-check
cmake --install build --prefix build/install >/dev/null
cmake -S examples -B build/example-out-of-tree -DCMAKE_PREFIX_PATH="$PWD/build/install" >/dev/null
cmake --build build/example-out-of-tree -j"$(nproc)" >/dev/null
echo "test.sh: examples/ built out of tree against the installed package (build/install)"
# The C example, linked against the installed libprogskin_c.so, joins a real server for 3 s.
c_out=$(python3 tests/with_server.py --server build/server/progskin-server -- \
  sh -c 'build/example-out-of-tree/c/c_game_loop "$PROGSKIN_HOST" "$PROGSKIN_PORT" 3 "$PROGSKIN_PIN"' 2>&1)
grep -q "I am character" <<<"$c_out" || { echo "test.sh: the installed C example failed:" >&2; echo "$c_out" >&2; exit 1; }
echo "test.sh: examples/c/c_game_loop (installed libprogskin_c.so) joined a server on loopback"
# The public headers beside <math.h>, <cmath> and <error.h>, and a C file, against the package.
cmake -S tests/install -B build/install-check -DCMAKE_PREFIX_PATH="$PWD/build/install" >/dev/null
cmake --build build/install-check -j"$(nproc)" >/dev/null
build/install-check/public_headers
