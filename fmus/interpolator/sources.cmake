# The Interpolator engine's C sources: one list for the FMU (fmus/CMakeLists.txt), the standalone driver
# interp_run (interpolator.cmake) and the fuzz targets (tests/fuzz). A new engine source file goes here only.
set(INTERPOLATOR_ENGINE ${INTERPOLATOR_DIR}/gcode_parser.c ${INTERPOLATOR_DIR}/gcode_number.c
    ${INTERPOLATOR_DIR}/tool_table.c ${INTERPOLATOR_DIR}/nurbs.c
    ${INTERPOLATOR_DIR}/path.c ${INTERPOLATOR_DIR}/feed_schedule.c ${INTERPOLATOR_DIR}/param_update.c
    ${INTERPOLATOR_DIR}/interpolator.c ${INTERPOLATOR_DIR}/cutter_comp.c ${INTERPOLATOR_DIR}/sinumerik.c)
