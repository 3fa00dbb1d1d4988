/* Fuzz harness of the interpolator's G-code parser (libFuzzer entry point; tests/fuzz/README.md).
 * Every input is parsed; an input that parses into a small program (<= 64 moves, <= 64 control points) also
 * goes through the whole engine: path, schedule, 3000 interpolation points with a feed-override change. */
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "interpolator.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

static void settings(InterpSettings *s) {
    int i;
    memset(s, 0, sizeof *s);
    s->limits.period = 1e-3;
    s->limits.acceleration = 1.0;
    s->limits.jerk = 100.0;
    s->limits.centripetal = 1.0;
    s->limits.chord = 1e-6;
    for (i = 0; i < 3; i++) s->limits.axis_acceleration[i] = 2.0, s->limits.axis_jerk[i] = 300.0;
    s->max_feed = 1.0 / 3.0;
    s->rapid_feed = 1.0 / 6.0;
    s->limits.max_feed = s->max_feed;
    s->update.method = METHOD_CORRECTOR;
    s->update.predictor = METHOD_TAYLOR2;
    s->update.tolerance = 1e-6;
    s->update.feedback = 1;
    s->update.rbf.width = 1.5;
    for (i = 0; i < RBF_INPUTS; i++) s->update.rbf.scale[i] = 1.0;
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size) {
    InterpSettings s;
    GcProgram program;
    InterpPrepared prepared;
    char error[1024];
    size_t k, points = 0;
    settings(&s);
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
