#!/usr/bin/env bash
# fuzz.sh — runs a libFuzzer target for a while, starting from (and adding to)
# its corpus: gltf (the glTF importer, fuzz/corpus/gltf), frame (the UDP
# frame stream as the client reads it, fuzz/corpus/frame), control (the
# players' control messages, fuzz/corpus/control), records (the
# parent-relative bone records, fuzz/corpus/records) or world (another
# node's messages on the world bus, fuzz/corpus/world). Needs clang
# (Debian clang-14 and libclang-rt-14-dev).
#
#   scripts/fuzz.sh [SECONDS] [gltf|frame|control|records|world]      (default 60 gltf)
set -euo pipefail
cd "$(dirname "$0")/.."
case "${1:-}" in -h|--help) sed -n '2,10p' "$0" | sed 's/^# \{0,1\}//'; exit 0;; esac
secs=${1:-60}
target=${2:-gltf}
case "$target" in
  gltf) exe=fuzz_gltf_import; net=OFF; len=65536;;
  frame) exe=fuzz_frame_stream; net=ON; len=1200;;
  control) exe=fuzz_control; net=ON; len=65536;;
  records) exe=fuzz_records; net=ON; len=4096;;
  world) exe=fuzz_world; net=ON; len=65536;;
  *) echo "fuzz.sh: unknown target $target (gltf, frame, control, records or world)" >&2; exit 2;;
esac
bash scripts/setup.sh
command -v clang++ >/dev/null || { echo "fuzz.sh: needs clang++ (apt-get install clang libclang-rt-14-dev)" >&2; exit 1; }
san="-fsanitize=address,undefined -fno-omit-frame-pointer"
cmake -S . -B build-fuzz -DCMAKE_CXX_COMPILER=clang++ -DCMAKE_BUILD_TYPE=RelWithDebInfo -DPROGSKIN_FUZZ=ON \
  -DPROGSKIN_BUILD_TESTS=OFF -DPROGSKIN_BUILD_BENCH=OFF -DPROGSKIN_BUILD_NET=$net \
  -DCMAKE_CXX_FLAGS="$san -fsanitize=fuzzer-no-link" -DCMAKE_EXE_LINKER_FLAGS="$san" >/dev/null
cmake --build build-fuzz -j"$(nproc)" --target $exe
mkdir -p build-fuzz/new-corpus-$target
build-fuzz/fuzz/$exe -max_total_time="$secs" -max_len=$len -rss_limit_mb=2048 \
  build-fuzz/new-corpus-$target fuzz/corpus/$target
echo "fuzz.sh: new inputs in build-fuzz/new-corpus-$target; copy interesting ones to fuzz/corpus/$target"
