/* SpindlePower: P = P_standby + P_idle + c1*|n| + c2*(MRR/1 cm3/s)^c3 + J*n*dn/dt + k*(n_cmd - n)*|n|,
 * equations and state update (the speed held over the previous step and the rate of change over the last one)
 * generated from models/power.py. Ranges of parameters and inputs are enforced by the wrapper from the
 * generated table; this file adds the one physical consistency check the equations cannot express. */
#include "fmu_instance.h"

FmuStatus model_exit_initialization(FmuInstance *instance) {
    instance->internal.warned_cutting_without_spindle = false;
    return FMU_OK;
}

FmuStatus model_do_step(FmuInstance *instance, double time, double step_size) {
    model_update_states(&instance->v, step_size);
    if (!instance->v.spindle_on && instance->v.mrr > 0.0 && !instance->internal.warned_cutting_without_spindle) {
        /* The cutting term is zero with the spindle off; the importer probably wired MRR wrongly. */
        instance->internal.warned_cutting_without_spindle = true;
        fmu_log(instance, FMU_WARNING, "logStatusWarning",
                "doStep: t = %g s: input 'mrr' = %g m3/s > 0 while 'spindle_on' is false; cutting power is 0 "
                "(reported once)", time, instance->v.mrr);
        return FMU_WARNING;
    }
    return FMU_OK;
}

void model_update_outputs(FmuInstance *instance) { model_evaluate_equations(&instance->v); }

void model_free_internal(FmuInstance *instance) { (void)instance; }
