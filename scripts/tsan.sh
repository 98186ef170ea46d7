#!/usr/bin/env bash
# tsan.sh — the networking tests under ThreadSanitizer: configures build-tsan
# (-DPROGSKIN_TSAN=ON, no benchmarks), builds the multiplayer, security and
# threads tests and progskin-client (which the multiplayer test starts), and
# runs them with every in-process server at $PROGSKIN_TEST_THREADS tick
# threads (default 3: more threads than this machine's cores, the control
# thread beside them). Any report fails the run (halt_on_error).
#
#   scripts/tsan.sh [GTEST_FILTER]        (default: every test of the three)
#   JOBS=N   build jobs (default 2)
set -euo pipefail
cd "$(dirname "$0")/.."
case "${1:-}" in -h|--help) sed -n '2,10p' "$0" | sed 's/^# \{0,1\}//'; exit 0;; esac
filter=${1:-*}
jobs=${JOBS:-2}
start=$(date +%s)
launcher=()
command -v ccache >/dev/null && launcher=(-DCMAKE_CXX_COMPILER_LAUNCHER=ccache -DCMAKE_C_COMPILER_LAUNCHER=ccache)
cmake -S . -B build-tsan -DCMAKE_BUILD_TYPE=RelWithDebInfo -DPROGSKIN_TSAN=ON -DPROGSKIN_BUILD_BENCH=OFF \
  "${launcher[@]}" >/dev/null
tests=(test_net_threads test_net_multiplayer test_net_security)
cmake --build build-tsan -j"$jobs" --target "${tests[@]}" progskin-client
built=$(date +%s)
export PROGSKIN_TEST_THREADS=${PROGSKIN_TEST_THREADS:-3}
# OpenSSL and libsodium are not instrumented; their own locks are seen
# through the pthread interceptors. history_size: deeper stacks of the
# earlier access in a report.
export TSAN_OPTIONS="halt_on_error=1 second_deadlock_stack=1 history_size=4 ${TSAN_OPTIONS:-}"
status=0
for t in "${tests[@]}"; do
  echo "tsan.sh: $t (server at $PROGSKIN_TEST_THREADS tick threads)"
  if ! "build-tsan/tests/$t" --gtest_filter="$filter" --gtest_brief=1; then
    echo "tsan.sh: $t FAILED" >&2
    status=1
  fi
done
end=$(date +%s)
echo "tsan.sh: build $((built - start)) s, tests $((end - built)) s"
exit $status
