# Interpolator: included by fmus/CMakeLists.txt after its add_fmu(Interpolator ...) line (which packs
# resources/program.nc, the default part program, into both FMUs).
# - builds the standalone driver interp_run (benchmark, tests) from the same engine sources as the FMU;
# - builds the fuzz harness with gcc + AddressSanitizer/UBSan as fuzz_gcode_replay and replays the committed
#   corpus in ctest (fuzz_corpus_replay); libFuzzer runs: `make fuzz` (tests/fuzz/run_fuzz.sh, clang).
set(INTERPOLATOR_DIR ${CMAKE_CURRENT_SOURCE_DIR}/interpolator)
set(INTERPOLATOR_ENGINE ${INTERPOLATOR_DIR}/gcode_parser.c ${INTERPOLATOR_DIR}/nurbs.c ${INTERPOLATOR_DIR}/path.c
    ${INTERPOLATOR_DIR}/feed_schedule.c ${INTERPOLATOR_DIR}/param_update.c ${INTERPOLATOR_DIR}/interpolator.c)

add_executable(interp_run ${INTERPOLATOR_DIR}/tools/interp_run.c ${INTERPOLATOR_ENGINE})
target_include_directories(interp_run PRIVATE ${INTERPOLATOR_DIR})
target_compile_options(interp_run PRIVATE ${FMU_WARNINGS} -O2)
target_link_libraries(interp_run PRIVATE m)
set_target_properties(interp_run PROPERTIES RUNTIME_OUTPUT_DIRECTORY ${CMAKE_BINARY_DIR}/tools)

add_executable(fuzz_gcode_replay ${CMAKE_SOURCE_DIR}/tests/fuzz/fuzz_gcode.c ${CMAKE_SOURCE_DIR}/tests/fuzz/replay.c
               ${INTERPOLATOR_ENGINE})
target_include_directories(fuzz_gcode_replay PRIVATE ${INTERPOLATOR_DIR})
target_compile_options(fuzz_gcode_replay PRIVATE ${FMU_WARNINGS} -fsanitize=address,undefined
                       -fno-sanitize-recover=all -fno-omit-frame-pointer)
target_link_options(fuzz_gcode_replay PRIVATE -fsanitize=address,undefined)
target_link_libraries(fuzz_gcode_replay PRIVATE m)
set_target_properties(fuzz_gcode_replay PROPERTIES RUNTIME_OUTPUT_DIRECTORY ${CMAKE_BINARY_DIR}/tools)
add_test(NAME fuzz_corpus_replay COMMAND fuzz_gcode_replay ${CMAKE_SOURCE_DIR}/tests/fuzz/corpus)
set_tests_properties(fuzz_corpus_replay PROPERTIES ENVIRONMENT "ASAN_OPTIONS=detect_leaks=1:abort_on_error=1")
