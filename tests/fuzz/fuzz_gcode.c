/* Fuzz harness of the interpolator's G-code parser (libFuzzer entry point; tests/fuzz/README.md).
 * Every input is parsed; an input that parses into a small program (<= 64 moves, <= 64 control points) also
 * goes through the whole engine: path, schedule, 3000 interpolation points with a feed-override change. The
 * settings are the model definition's defaults (interp_default_settings), as interp_run's. */
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "interp_settings.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size) {
    InterpSettings s;
    GcProgram program;
    InterpPrepared prepared;
    char error[1024];
    size_t k, points = 0;
    interp_default_settings(&s); /* the model definition's defaults (generated start values) */
    if (size > 0) s.update.method = 1 + data[0] % 4, s.update.predictor = 1 + data[size - 1] % 3;
    if (gc_parse((const char *)data, size, "fuzz.nc", &s.gcode, &program, error, sizeof error) != 0) return 0;
    for (k = 0; k < program.n_curves; k++) points += (size_t)program.curves[k].n_points;
    if (program.n_moves > 64 || points > 64) {
        gc_free(&program);
        return 0;
    }
    gc_free(&program);
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
