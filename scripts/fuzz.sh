#!/usr/bin/env bash
# fuzz.sh — runs the libFuzzer target for the glTF importer for a while,
# starting from (and adding to) fuzz/corpus/gltf. Needs clang (Debian clang-14
# and libclang-rt-14-dev).
#
#   scripts/fuzz.sh [SECONDS]      (default 60)
set -euo pipefail
cd "$(dirname "$0")/.."
case "${1:-}" in -h|--help) sed -n '2,7p' "$0" | sed 's/^# \{0,1\}//'; exit 0;; esac
secs=${1:-60}
bash scripts/setup.sh
command -v clang++ >/dev/null || { echo "fuzz.sh: needs clang++ (apt-get install clang libclang-rt-14-dev)" >&2; exit 1; }
san="-fsanitize=address,undefined -fno-omit-frame-pointer"
cmake -S . -B build-fuzz -DCMAKE_CXX_COMPILER=clang++ -DCMAKE_BUILD_TYPE=RelWithDebInfo -DPROGSKIN_FUZZ=ON \
  -DPROGSKIN_BUILD_TESTS=OFF -DPROGSKIN_BUILD_BENCH=OFF -DPROGSKIN_BUILD_NET=OFF \
  -DCMAKE_CXX_FLAGS="$san -fsanitize=fuzzer-no-link" -DCMAKE_EXE_LINKER_FLAGS="$san" >/dev/null
cmake --build build-fuzz -j"$(nproc)" --target fuzz_gltf_import
mkdir -p build-fuzz/new-corpus
build-fuzz/fuzz/fuzz_gltf_import -max_total_time="$secs" -max_len=65536 -rss_limit_mb=2048 \
  build-fuzz/new-corpus fuzz/corpus/gltf
echo "fuzz.sh: new inputs in build-fuzz/new-corpus; copy interesting ones to fuzz/corpus/gltf"
