/* CuttingForce: the mechanistic milling force of models/cutting_force.py. The force equations and
 * the spindle-angle update are generated (model_generated.c); this file keeps what casadi cannot
 * express, the displacement history behind the regenerative chip thickness:
 *
 * - each doStep records (t, displacement_x, displacement_y), the inputs at the start of the step,
 *   in a ring of `history_size` samples in the instance heap (so FMU states carry it). The heap
 *   starts small and doubles as samples arrive until it holds history_size of them: a short run
 *   (and its FMU states) stays small, and the values do not depend on the growth;
 * - before the outputs are computed, the displacement one tooth period T = 2*pi/(N*omega) ago is
 *   interpolated linearly over those samples and the current inputs at the instance time, and
 *   written to the native states delayed_displacement_x/y. Before the oldest sample the oldest
 *   value is used (no history yet: no regeneration).
 *
 * ForceReference in models/cutting_force.py is the same algorithm in Python; the tests hold the
 * two equal to 1e-12. */
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include "cutting_state.h"
#include "fmu_instance.h"

#define TWO_PI 6.283185307179586 /* 2.0 * math.pi */
#define OMEGA_MIN 1.0            /* rad/s: models/cutting_force.py OMEGA_MIN, below it the spindle is stopped */
#define SAMPLE_SIZE 3            /* t, x, y */
#define INITIAL_SAMPLES 256      /* the heap's first size, in samples */

static double tooth_period(const ModelVariables *v) {
    return TWO_PI / ((double)v->n_flutes * fmax(v->spindle_speed, OMEGA_MIN));
}

/* Sample k of the history, 0 the oldest. */
static const double *sample(const FmuInstance *instance, size_t k) {
    const ModelInternal *in = &instance->internal;
    return instance->heap + SAMPLE_SIZE * ((in->next + in->capacity - in->count + k) % in->capacity);
}

/* Whether sample lo is the last one at or before td (index n: the current inputs, after td). */
static bool brackets(const FmuInstance *instance, size_t lo, double td) {
    size_t n = instance->internal.count;
    return lo < n && sample(instance, lo)[0] <= td && (lo + 1 == n || sample(instance, lo + 1)[0] > td);
}

/* The displacement at time - T: linear between the samples and the current inputs at `time`. The
 * sample found is remembered: one step later it is mostly the same or the one before (the ring
 * dropped its oldest sample), checked before a bisection; the sample times increase strictly, so
 * the answer is the bisection's. */
static void delayed_displacement(FmuInstance *instance, double *x, double *y) {
    const ModelVariables *v = &instance->v;
    size_t n = instance->internal.count, lo = 0, hi = n, hint = instance->internal.hint;
    double td = instance->time - tooth_period(v);
    const double *a, *b;
    double current[SAMPLE_SIZE];
    current[0] = instance->time;
    current[1] = v->displacement_x;
    current[2] = v->displacement_y;
    a = n > 0 ? sample(instance, 0) : current;
    if (td <= a[0]) {
        *x = a[1];
        *y = a[2];
        return;
    }
    if (brackets(instance, hint, td)) {
        lo = hint;
    } else if (hint > 0 && brackets(instance, hint - 1, td)) {
        lo = hint - 1;
    } else if (brackets(instance, hint + 1, td)) {
        lo = hint + 1;
    } else {
        /* t(lo) <= td < t(hi), where index n is the current inputs */
        while (hi - lo > 1) {
            size_t mid = lo + (hi - lo) / 2;
            if (sample(instance, mid)[0] <= td)
                lo = mid;
            else
                hi = mid;
        }
    }
    instance->internal.hint = lo;
    a = sample(instance, lo);
    b = lo + 1 < n ? sample(instance, lo + 1) : current;
    {
        double w = (td - a[0]) / (b[0] - a[0]);
        *x = a[1] + w * (b[1] - a[1]);
        *y = a[2] + w * (b[2] - a[2]);
    }
}

FmuStatus model_exit_initialization(FmuInstance *instance) {
    ModelInternal *in = &instance->internal;
    size_t capacity = (size_t)instance->v.history_size; /* >= 16: checked against its range */
    if (capacity > INITIAL_SAMPLES) capacity = INITIAL_SAMPLES;
    if (fmu_allocate_heap(instance, "ExitInitializationMode", SAMPLE_SIZE * capacity) != FMU_OK) return FMU_ERROR;
    in->capacity = capacity;
    in->count = 0;
    in->next = 0;
    in->hint = 0;
    in->warned_stopped = false;
    return FMU_OK;
}

/* A full heap smaller than history_size doubles (up to history_size). Full and not yet wrapped,
 * its samples are in order from slot 0, so they keep their slots and the next goes after them. */
static FmuStatus grow_history(FmuInstance *instance) {
    ModelInternal *in = &instance->internal;
    size_t limit = (size_t)instance->v.history_size, capacity = 2 * in->capacity;
    size_t bytes = SAMPLE_SIZE * in->count * sizeof(double);
    double *kept = malloc(bytes);
    if (!kept) {
        fmu_log(instance, FMU_ERROR, "logStatusError", "DoStep: out of memory for the displacement history");
        return FMU_ERROR;
    }
    memcpy(kept, instance->heap, bytes);
    if (capacity > limit) capacity = limit;
    if (fmu_allocate_heap(instance, "DoStep", SAMPLE_SIZE * capacity) != FMU_OK) {
        free(kept);
        return FMU_ERROR;
    }
    memcpy(instance->heap, kept, bytes);
    free(kept);
    in->capacity = capacity;
    in->next = in->count;
    return FMU_OK;
}

FmuStatus model_do_step(FmuInstance *instance, double time, double step_size) {
    ModelVariables *v = &instance->v;
    ModelInternal *in = &instance->internal;
    FmuStatus status;
    double *slot;
    if (in->count == in->capacity && in->capacity < (size_t)v->history_size && grow_history(instance) != FMU_OK)
        return FMU_ERROR;
    slot = instance->heap + SAMPLE_SIZE * in->next;
    slot[0] = time;
    slot[1] = v->displacement_x;
    slot[2] = v->displacement_y;
    in->next = (in->next + 1) % in->capacity;
    if (in->count < in->capacity) in->count++;

    if (in->count == (size_t)v->history_size && v->spindle_speed >= OMEGA_MIN && v->axial_depth > 0.0) {
        double period = tooth_period(v), end = time + step_size, oldest = sample(instance, 0)[0];
        if (oldest > end - period) {
            fmu_log(instance, FMU_ERROR, "logStatusError",
                    "doStep: t = %g s: the displacement history (history_size = %d samples, %g s at this step size) "
                    "is shorter than one tooth period 2*pi/(n_flutes*spindle_speed) = %g s (n_flutes = %d, "
                    "spindle_speed = %g rad/s); set history_size to at least %.0f or use larger steps",
                    time, (int)v->history_size, end - oldest, period, (int)v->n_flutes, v->spindle_speed,
                    ceil(period / step_size) + 2.0);
            return FMU_ERROR;
        }
    }

    /* a stopped tool fed into the material would break; the model cuts nothing instead */
    status = warn_feeding_a_stopped_spindle(instance, time, v->spindle_speed, OMEGA_MIN, v->feed_velocity_x,
                                            v->feed_velocity_y, v->axial_depth, v->entry_angle, v->exit_angle,
                                            &in->warned_stopped);

    model_update_states(v, step_size);
    return status;
}

void model_update_outputs(FmuInstance *instance) {
    ModelVariables *v = &instance->v;
    delayed_displacement(instance, &v->states.delayed_displacement_x, &v->states.delayed_displacement_y);
    model_evaluate_equations(v);
}

void model_free_internal(FmuInstance *instance) { (void)instance; }
