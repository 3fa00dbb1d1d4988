/* Fuzz harness of the interpolator's G-code parser (libFuzzer entry point; tests/fuzz/README.md).
 * Every input is parsed in each dialect (fanuc, linuxcnc, sinumerik) with a small tool table; the first dialect
 * in which it parses into a small program (<= 64 moves, <= 64 control points) also takes it through the whole
 * engine: path, schedule, 3000 interpolation points with a feed-override change. The other settings are the
 * model definition's defaults (interp_default_settings), as interp_run's. */
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "interp_settings.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size) {
    static const GcTool TOOLS[3] = {
        {1, "END10", 0.01, 0.0005, 0.05, 0.04, 0.5235987755982988, 3},
        {2, "DRILL6", 0.006, 0.0, 0.08, 0.05, 0.5235987755982988, 2},
        {12, "", 0.003175, 0.0, 0.04, 0.0, 0.0, 0}};
    static const int DIALECTS[3] = {DIALECT_FANUC, DIALECT_LINUXCNC, DIALECT_SINUMERIK};
    InterpSettings s;
    GcProgram program;
    InterpPrepared prepared;
    char error[1024];
    size_t k, points;
    int d, small = 0;
    interp_default_settings(&s); /* the model definition's defaults (generated start values) */
    if (size > 0) s.update.method = 1 + data[0] % 4, s.update.predictor = 1 + data[size - 1] % 3;
    s.gcode.tools = TOOLS;
    s.gcode.n_tools = 3;
    for (d = 0; d < 3 && !small; d++) {
        s.gcode.dialect = DIALECTS[d];
        if (gc_parse((const char *)data, size, "fuzz.nc", &s.gcode, &program, error, sizeof error) != 0) continue;
        for (k = 0, points = 0; k < program.n_curves; k++) points += (size_t)program.curves[k].n_points;
        small = program.n_moves <= 64 && points <= 64;
        gc_free(&program);
    }
    if (!small) return 0;
    s.gcode.dialect = DIALECTS[d - 1];
    if (interp_prepare((const char *)data, size, "fuzz.nc", &s, &prepared, error, sizeof error) == 0) {
        InterpLayout layout;
        InterpState state;
        double *heap = calloc(interp_heap_size(&prepared), sizeof *heap);
        if (heap) {
            int tick;
            interp_install(&prepared, heap, &layout);
            interp_start(&state, &s);
            if (interp_set_override(heap, &layout, &state, &s, 1.0) == 0) {
                for (tick = 0; tick < 3000 && !state.out.finished; tick++) {
                    if (tick == 400 && interp_set_override(heap, &layout, &state, &s, 0.5) != 0) break;
                    if (tick == 900 && interp_set_override(heap, &layout, &state, &s, 0.0) != 0) break;
                    if (tick == 1000 && interp_set_override(heap, &layout, &state, &s, 1.5) != 0) break;
                    interp_tick(heap, &layout, &state, &s);
                }
            }
            free(heap);
        }
        interp_release(&prepared);
    }
    return 0;
}
