/* CuttingForce: the mechanistic milling force of models/cutting_force.py. The force equations and
 * the spindle-angle update are generated (model_generated.c); this file keeps what casadi cannot
 * express, the displacement history behind the regenerative chip thickness (fmus/common/
 * displacement_history.c, shared with ForceNet): each doStep records the displacement inputs in a ring
 * in the instance heap, and before the outputs are computed the displacement one tooth period
 * T = 2*pi/(N*omega) ago is interpolated and written to the native states delayed_displacement_x/y.
 *
 * ForceReference in models/cutting_force.py is the same algorithm in Python; the tests hold the
 * two equal to 1e-12. */
#include <math.h>
#include "cutting_state.h"
#include "fmu_instance.h"
#include "model_constants.h" /* OMEGA_MIN, TWO_PI: generated from models/cutting_force.py */

static double tooth_period(const ModelVariables *v) {
    return TWO_PI / ((double)v->n_flutes * fmax(v->spindle_speed, OMEGA_MIN));
}

FmuStatus model_exit_initialization(FmuInstance *instance) {
    instance->internal.warned_stopped = false;
    return history_start(instance, &instance->internal.history, 0, instance->v.history_size,
                         "ExitInitializationMode") == 0 ? FMU_OK : FMU_ERROR;
}

FmuStatus model_do_step(FmuInstance *instance, double time, double step_size) {
    ModelVariables *v = &instance->v;
    ModelInternal *in = &instance->internal;
    FmuStatus status;
    if (history_record(instance, &in->history, v->history_size, time, step_size, v->displacement_x,
                       v->displacement_y, tooth_period(v), v->spindle_speed >= OMEGA_MIN && v->axial_depth > 0.0,
                       v->n_flutes, v->spindle_speed) != 0)
        return FMU_ERROR;
    /* a stopped tool fed into the material would break; the model cuts nothing instead */
    status = warn_feeding_a_stopped_spindle(instance, time, v->spindle_speed, OMEGA_MIN, v->feed_velocity_x,
                                            v->feed_velocity_y, v->axial_depth, v->entry_angle, v->exit_angle,
                                            &in->warned_stopped);
    model_update_states(v, step_size);
    return status;
}

void model_update_outputs(FmuInstance *instance) {
    ModelVariables *v = &instance->v;
    history_delayed(instance, &instance->internal.history, instance->time, tooth_period(v), v->displacement_x,
                    v->displacement_y, &v->states.delayed_displacement_x, &v->states.delayed_displacement_y);
    model_evaluate_equations(v);
}

void model_free_internal(FmuInstance *instance) { (void)instance; }
