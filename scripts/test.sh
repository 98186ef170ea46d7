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
# A C program against the C library alone: find_package(progskin COMPONENTS c)
# with the C++ libraries' packages disabled, and pkg-config (progskin_c.pc),
# whose build then joins a server.
rm -rf build/install-c-only && mkdir -p build/install-c-only
cmake -S tests/install/c_only -B build/install-c-only/cmake -DCMAKE_PREFIX_PATH="$PWD/build/install" >/dev/null
cmake --build build/install-c-only/cmake >/dev/null
# shellcheck disable=SC2046  # pkg-config's flags are meant to split
cc -std=c99 -Wall -Wextra -pedantic -Werror -o build/install-c-only/c_game_loop examples/c/c_game_loop.c \
  $(PKG_CONFIG_PATH="$PWD/build/install/lib/pkgconfig" pkg-config --cflags --libs progskin_c) -lm
c_out=$(LD_LIBRARY_PATH="$PWD/build/install/lib" python3 tests/with_server.py --server build/server/progskin-server -- \
  sh -c 'build/install-c-only/c_game_loop "$PROGSKIN_HOST" "$PROGSKIN_PORT" 2 "$PROGSKIN_PIN"' 2>&1)
grep -q "I am character" <<<"$c_out" || { echo "test.sh: the C example built with pkg-config failed:" >&2; echo "$c_out" >&2; exit 1; }
echo "test.sh: a C program built with find_package(progskin COMPONENTS c) alone, and with pkg-config progskin_c (it joined a server)"
# The public headers beside <math.h>, <cmath> and <error.h>, and a C file, against the package.
cmake -S tests/install -B build/install-check -DCMAKE_PREFIX_PATH="$PWD/build/install" >/dev/null
cmake --build build/install-check -j"$(nproc)" >/dev/null
build/install-check/public_headers
