# Interpolator: included by fmus/CMakeLists.txt after its add_fmu(Interpolator ...) line (which packs
# resources/program.nc, the default part program, into both FMUs).
# builds the standalone driver interp_run (benchmark, tests) from the same engine sources as the FMU, with the
# FMU's generated variables (model_generated.c: the parameters' start values; model_table_fmi3.c: --param by name)
# and constants (model_constants.h). (The parser's fuzz target, gcode, is built by tests/fuzz/CMakeLists.txt from
# the FMU's sources minus model.c.)
# INTERPOLATOR_DIR and the engine's sources INTERPOLATOR_ENGINE: sources.cmake (included before add_fmu).

set(INTERPOLATOR_GENERATED ${CMAKE_BINARY_DIR}/generated/Interpolator)
add_executable(interp_run ${INTERPOLATOR_DIR}/tools/interp_run.c ${INTERPOLATOR_ENGINE} ${INTERPOLATOR_DIR}/interp_settings.c
               ${INTERPOLATOR_GENERATED}/model_generated.c ${INTERPOLATOR_GENERATED}/model_table_fmi3.c)
target_include_directories(interp_run PRIVATE ${INTERPOLATOR_DIR} ${INTERPOLATOR_GENERATED} ${FMU_COMMON_DIR})
target_compile_options(interp_run PRIVATE ${FMU_WARNINGS} -O2)
target_link_libraries(interp_run PRIVATE m)
set_target_properties(interp_run PROPERTIES RUNTIME_OUTPUT_DIRECTORY ${CMAKE_BINARY_DIR}/tools)
