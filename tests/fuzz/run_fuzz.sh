#!/bin/sh
# libFuzzer run of one fuzz target (tests/fuzz/README.md):
#
#   tests/fuzz/run_fuzz.sh [target=gcode] [seconds=600]     (make fuzz FUZZ_TARGET=gcode FUZZ_TIME=600)
#   tests/fuzz/run_fuzz.sh list                              the targets
#
# Targets: gcode (the Interpolator's G-code parser and engine), forcenet (the ForceNet weights file and resource
# location), fmi_<FMU>_fmi<2|3> (the FMI entry points of one FMU and version, random call sequences).
# Configures a clang build folder ($FUZZ_BUILD, default build-fuzz) with -DFUZZ_LIBFUZZER=ON, builds the target
# with -fsanitize=fuzzer,address,undefined (installs clang with apt-get when it is missing and we are root), and
# fuzzes for the given time with one worker, starting from the committed seed corpus (read only). New inputs go
# to $FUZZ_OUT/corpus, crashes, hangs (10 s per input) and sanitizer reports to $FUZZ_OUT/artifacts ($FUZZ_OUT
# defaults to build/fuzz/<target>). Exit status 0: nothing found. A finding replays with the gcc/ASan build:
# build/tools/fuzz_<target>_replay <file> (FUZZ_FMI_TRACE=1 prints the FMI calls it makes).
set -eu
REPO=$(cd "$(dirname "$0")/../.." && pwd)
TARGET=${1:-gcode}
case "$TARGET" in
[0-9]*) TIME=$TARGET; TARGET=gcode ;; # the old form: run_fuzz.sh <seconds>
*) TIME=${2:-600} ;;
esac
CLANG=${CLANG:-clang}
PYTHON=${PYTHON:-python3}
BUILD=${FUZZ_BUILD:-$REPO/build-fuzz}
if ! command -v "$CLANG" >/dev/null 2>&1; then
    if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
        echo "run_fuzz: installing clang (apt-get)"
        apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq clang >/dev/null
    else
        echo "run_fuzz: clang not found (install it, or run as root to let this script install it)" >&2
        exit 2
    fi
fi
if [ ! -f "$BUILD/CMakeCache.txt" ]; then
    CC="$CLANG" cmake -S "$REPO" -B "$BUILD" -DFUZZ_LIBFUZZER=ON -DCMAKE_BUILD_TYPE=RelWithDebInfo \
        -DPython3_EXECUTABLE="$(command -v "$PYTHON")" >/dev/null
fi
if [ "$TARGET" = list ]; then
    cmake --build "$BUILD" --target help | sed -n 's/^\.\.\. fuzz_\(.*\)$/\1/p' | sort
    exit 0
fi
cmake --build "$BUILD" --target "fuzz_$TARGET" -j "${JOBS:-2}" >/dev/null
OUT=${FUZZ_OUT:-$REPO/build/fuzz/$TARGET}
mkdir -p "$OUT/corpus" "$OUT/artifacts"
SEEDS="$REPO/tests/fuzz/corpus/$TARGET"
OPTIONS=""
case "$TARGET" in
gcode) OPTIONS="-max_len=8192 -dict=$REPO/tests/fuzz/gcode.dict" ;;
forcenet) OPTIONS="-max_len=65536" ;;
fmi_*)
    OPTIONS="-max_len=4096"
    [ -d "$SEEDS" ] || SEEDS=""
    SEEDS="$REPO/tests/fuzz/corpus/fmi $SEEDS"
    ;;
esac
echo "run_fuzz: $TARGET for $TIME s ($("$CLANG" --version | head -n 1))"
# shellcheck disable=SC2086  # OPTIONS and SEEDS are lists
exec "$BUILD/tools/fuzz_$TARGET" -max_total_time="$TIME" -timeout=10 -rss_limit_mb=2048 $OPTIONS \
    -artifact_prefix="$OUT/artifacts/" -print_final_stats=1 "$OUT/corpus" $SEEDS
