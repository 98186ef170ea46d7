#!/usr/bin/env bash
# tsan.sh — the networking tests under ThreadSanitizer: configures build-tsan
# (-DPROGSKIN_TSAN=ON, no benchmarks), builds the multiplayer, security and
# threads tests, the encoder's (its tick on a pool) and the load generator's
# threaded run (its players on three threads against an in-process server), progskin-client and examples/game_loop (which the
# multiplayer tests start), and runs them with every in-process server at
# $PROGSKIN_TEST_THREADS tick threads (default 3: more threads than this
# machine's cores, the control thread beside them). A ThreadSanitizer report
# fails the run (halt_on_error, exit code 66). Under TSan everything runs
# 5-20 times slower, so the tests' timed checks (seen within 1 s, error at a
# given rate) may fail without a race: those are listed, not counted (the
# normal build checks them).
#
#   scripts/tsan.sh [GTEST_FILTER]        (default: every test of the first four,
#                                          and the load generator's threaded one)
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
tests=(test_net_threads test_net_multiplayer test_net_security test_frame_encoder test_net_loadgen)
# The load generator's other tests run it on one thread: only its threaded one here.
filter_of() { if [[ $1 == test_net_loadgen && $filter == '*' ]]; then echo 'NetLoadgen.ThreeThreads*'; else echo "$filter"; fi; }
cmake --build build-tsan -j"$jobs" --target "${tests[@]}" progskin-client game_loop
built=$(date +%s)
export PROGSKIN_TEST_THREADS=${PROGSKIN_TEST_THREADS:-3}
# OpenSSL and libsodium are not instrumented; their own locks are seen
# through the pthread interceptors. history_size: deeper stacks of the
# earlier access in a report.
export TSAN_OPTIONS="halt_on_error=1 exitcode=66 second_deadlock_stack=1 history_size=4 ${TSAN_OPTIONS:-}"
status=0
mkdir -p build-tsan/logs
for t in "${tests[@]}"; do
  echo "tsan.sh: $t (server at $PROGSKIN_TEST_THREADS tick threads)"
  log=build-tsan/logs/$t.log
  rc=0
  "build-tsan/tests/$t" --gtest_filter="$(filter_of "$t")" --gtest_brief=1 >"$log" 2>&1 || rc=$?
  if [[ $rc == 66 ]] || grep -q "WARNING: ThreadSanitizer" "$log"; then
    echo "tsan.sh: $t: DATA RACE (ThreadSanitizer), see $log" >&2
    sed -n '/WARNING: ThreadSanitizer/,/^SUMMARY/p' "$log" >&2
    status=1
  elif [[ $rc != 0 ]]; then
    echo "tsan.sh: $t: no race reported; failed checks under TSan's slowdown (timed checks; the normal build runs them):" >&2
    grep -E '^\[  FAILED  \]' "$log" | sort -u >&2 || true
  else
    echo "tsan.sh: $t: passed, no race reported"
  fi
done
end=$(date +%s)
echo "tsan.sh: build $((built - start)) s, tests $((end - built)) s"
exit $status
