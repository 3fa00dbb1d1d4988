#!/bin/sh
# libFuzzer run of the interpolator's G-code parser and engine (harness tests/fuzz/fuzz_gcode.c):
#
#   tests/fuzz/run_fuzz.sh [seconds=600]          (make fuzz FUZZ_TIME=600)
#
# Builds the harness with clang -fsanitize=fuzzer,address,undefined (installs clang with apt-get when it is
# missing and we are root), then fuzzes for the given time starting from the committed seed corpus
# (tests/fuzz/corpus, read only) with the G-code dictionary. New inputs go to $FUZZ_OUT/corpus, crashes,
# hangs (timeout 10 s per input) and sanitizer reports to $FUZZ_OUT/artifacts (FUZZ_OUT defaults to
# build/fuzz). Exit status: 0 when nothing was found. Reproduce a finding with build/tools/fuzz_gcode_replay.
set -eu
TIME=${1:-600}
REPO=$(cd "$(dirname "$0")/../.." && pwd)
OUT=${FUZZ_OUT:-$REPO/build/fuzz}
CLANG=${CLANG:-clang}
if ! command -v "$CLANG" >/dev/null 2>&1; then
    if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
        echo "run_fuzz: installing clang (apt-get)"
        apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq clang >/dev/null
    else
        echo "run_fuzz: clang not found (install it, or run as root to let this script install it)" >&2
        exit 2
    fi
fi
SRC=$REPO/fmus/interpolator
mkdir -p "$OUT/corpus" "$OUT/artifacts"
"$CLANG" -std=c99 -g -O1 -fsanitize=fuzzer,address,undefined -fno-sanitize-recover=all -I"$SRC" \
    "$REPO/tests/fuzz/fuzz_gcode.c" "$SRC/gcode_parser.c" "$SRC/nurbs.c" "$SRC/path.c" "$SRC/feed_schedule.c" \
    "$SRC/param_update.c" "$SRC/interpolator.c" -lm -o "$OUT/fuzz_gcode"
echo "run_fuzz: fuzzing for $TIME s ($("$CLANG" --version | head -n 1))"
"$OUT/fuzz_gcode" -max_total_time="$TIME" -timeout=10 -rss_limit_mb=2048 -max_len=8192 \
    -dict="$REPO/tests/fuzz/gcode.dict" -artifact_prefix="$OUT/artifacts/" -print_final_stats=1 \
    "$OUT/corpus" "$REPO/tests/fuzz/corpus"
