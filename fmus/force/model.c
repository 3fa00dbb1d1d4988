/* CuttingForce: the mechanistic milling force of models/cutting_force.py. The force equations and
 * the spindle-angle update are generated (model_generated.c); this file keeps what casadi cannot
 * express, the displacement history behind the regenerative chip thickness (fmus/common/
 * displacement_history.c, shared with ForceNet): each doStep records the displacement inputs in a ring
 * in the instance heap, and before the outputs are computed the displacement one tooth period
 * T = 2*pi/(N*omega) ago is interpolated and written to the native states delayed_displacement_x/y (and k
 * periods ago to delayed_displacement_x/y_k, k = 2 .. regeneration_passes: multiple regeneration).
 *
 * ForceReference in models/cutting_force.py is the same algorithm in Python; the tests hold the
 * two equal to 1e-12. */
#include <math.h>
#include "cutting_state.h"
#include "fmu_instance.h"
#include "model_constants.h" /* OMEGA_MIN, TWO_PI, MAX_PASSES: generated from models/cutting_force.py */

#if MAX_PASSES != HISTORY_DELAYS
#error "regeneration_passes reaches MAX_PASSES tooth periods back: the history needs as many search hints"
#endif

static double tooth_period(const ModelVariables *v) {
    return TWO_PI / ((double)v->n_flutes * fmax(v->spindle_speed, OMEGA_MIN));
}

/* The model's time: the start time plus the step clock's (fmus/common/step_clock.h, as ForceNet's). */
static double clock_time(const FmuInstance *instance) {
    return instance->start_time + step_clock_seconds(&instance->internal.clock);
}

FmuStatus model_exit_initialization(FmuInstance *instance) {
    instance->internal.warned_stopped = false;
    instance->internal.clock.ns = 0.0;
    instance->internal.clock.rest = 0.0;
    return history_start(instance, &instance->internal.history, 0, instance->v.history_size,
                         "ExitInitializationMode") == 0 ? FMU_OK : FMU_ERROR;
}

FmuStatus model_do_step(FmuInstance *instance, double time, double step_size) {
    ModelVariables *v = &instance->v;
    ModelInternal *in = &instance->internal;
    StepClock clock = in->clock;
    const double start = clock_time(instance), h = step_clock_advance(&clock, time, step_size);
    FmuStatus status;
    if (history_record(instance, &in->history, v->history_size, start, h, v->displacement_x,
                       v->displacement_y, tooth_period(v), v->regeneration_passes,
                       v->spindle_speed >= OMEGA_MIN && v->axial_depth > 0.0, v->n_flutes, v->spindle_speed) != 0)
        return FMU_ERROR;
    /* a stopped tool fed into the material would break; the model cuts nothing instead */
    status = warn_feeding_a_stopped_spindle(instance, time, v->spindle_speed, OMEGA_MIN, v->feed_velocity_x,
                                            v->feed_velocity_y, v->axial_depth, v->entry_angle, v->exit_angle,
                                            &in->warned_stopped);
    model_update_states(v, h);
    in->clock = clock;
    return status;
}

void model_update_outputs(FmuInstance *instance) {
    ModelVariables *v = &instance->v;
    /* k tooth periods ago, k = 1 .. regeneration_passes (<= MAX_PASSES: its range) */
    double *delayed[MAX_PASSES][2] = {
        {&v->states.delayed_displacement_x, &v->states.delayed_displacement_y},
        {&v->states.delayed_displacement_x_2, &v->states.delayed_displacement_y_2},
        {&v->states.delayed_displacement_x_3, &v->states.delayed_displacement_y_3}};
    const double period = tooth_period(v);
    int k;
    for (k = 1; k <= MAX_PASSES; k++) {
        if (k == 1 || k <= v->regeneration_passes) {
            history_delayed(instance, &instance->internal.history, k - 1, clock_time(instance), k * period,
                            v->displacement_x, v->displacement_y, delayed[k - 1][0], delayed[k - 1][1]);
        } else { /* not looked back to: the surface one period back (the equations' extra terms then change nothing) */
            *delayed[k - 1][0] = *delayed[0][0];
            *delayed[k - 1][1] = *delayed[0][1];
        }
    }
    model_evaluate_equations(v);
}

void model_free_internal(FmuInstance *instance) { (void)instance; }
