#!/usr/bin/env bash
# Builds progskin and runs every test (the README's test command; CI runs this),
# then installs the package and builds examples/ out of tree against it, as a
# game would (find_package(progskin), progskin::client), and compiles
# tests/install against it.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/build.sh
ctest --test-dir build --output-on-failure -j"$(nproc)"
rm -rf build/install build/example-out-of-tree build/install-check
cmake --install build --prefix build/install >/dev/null
cmake -S examples -B build/example-out-of-tree -DCMAKE_PREFIX_PATH="$PWD/build/install" >/dev/null
cmake --build build/example-out-of-tree -j"$(nproc)" >/dev/null
echo "test.sh: examples/ built out of tree against the installed package (build/install)"
# The public headers beside <math.h>, <cmath> and <error.h>, and a C file, against the package.
cmake -S tests/install -B build/install-check -DCMAKE_PREFIX_PATH="$PWD/build/install" >/dev/null
cmake --build build/install-check -j"$(nproc)" >/dev/null
build/install-check/public_headers
