#!/bin/sh
# The sanitizer stage of `make test` (`make test-sanitize`; README "Tests"):
#
#   tests/run_sanitized.sh <python> <build dir configured with -DFMU_SANITIZE=ON> [pytest arguments...]
#
# Runs pytest with the FMUs and the stepper library of that build (MILLING_TWIN_FMU_DIR=<build>/fmus; the
# orchestrator finds <build>/stepper/ beside it) and gcc's ASan and UBSan runtimes preloaded, so that every FMU
# simulation of the selected tests -- in pytest's process and in the processes it starts, which inherit the
# environment -- runs instrumented. Leak detection is off: the interpreter's own allocations are not ours
# (leaks are checked by valgrind in ctest). Every report is written to <build>/sanitizer-reports/ as well as
# aborting the process that made it: the stage fails when pytest fails or when any report exists, so a report
# from a subprocess whose failure a test expected still fails it. MILLING_TWIN_SANITIZED=1 tells the few tests
# that repeat one check over many random inputs to take fewer (each says how many and why).
set -eu
PYTHON=$1
BUILD=$(cd "$2" && pwd)
shift 2
grep -q '^FMU_SANITIZE:BOOL=ON' "$BUILD/CMakeCache.txt" || { echo "run_sanitized: $BUILD is not a FMU_SANITIZE=ON build" >&2; exit 2; }
REPORTS=$BUILD/sanitizer-reports
rm -rf "$REPORTS"
mkdir -p "$REPORTS"
ASAN_RUNTIME=$(gcc -print-file-name=libasan.so)
UBSAN_RUNTIME=$(gcc -print-file-name=libubsan.so)
for runtime in "$ASAN_RUNTIME" "$UBSAN_RUNTIME"; do
    [ -f "$runtime" ] || { echo "run_sanitized: gcc has no sanitizer runtime ($runtime)" >&2; exit 2; }
done
status=0
env LD_PRELOAD="$ASAN_RUNTIME $UBSAN_RUNTIME" \
    ASAN_OPTIONS="detect_leaks=0:abort_on_error=1:halt_on_error=1:log_path=$REPORTS/asan" \
    UBSAN_OPTIONS="halt_on_error=1:print_stacktrace=1:log_path=$REPORTS/ubsan" \
    MILLING_TWIN_FMU_DIR="$BUILD/fmus" MILLING_TWIN_SANITIZED=1 \
    "$PYTHON" -m pytest -p no:cacheprovider "$@" || status=$?
if [ -n "$(ls -A "$REPORTS")" ]; then
    for report in "$REPORTS"/*; do
        echo "==== $report"
        head -c 20000 "$report"
    done
    echo "run_sanitized: sanitizer reports in $REPORTS (above)" >&2
    exit 1
fi
exit "$status"
