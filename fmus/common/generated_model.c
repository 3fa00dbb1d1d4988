/* Model hooks for models that are entirely their models/ definition: outputs from the generated
 * equations, states (if any) from the generated update. A model with more to do (checks, memory,
 * code that casadi cannot express) writes its own model.c. */
#include "fmu_instance.h"

FmuStatus model_exit_initialization(FmuInstance *instance) {
    (void)instance;
    return FMU_OK;
}

FmuStatus model_do_step(FmuInstance *instance, double time, double step_size) {
    (void)time;
    model_update_states(&instance->v, step_size);
    return FMU_OK;
}

void model_update_outputs(FmuInstance *instance) { model_evaluate_equations(&instance->v); }

void model_free_internal(FmuInstance *instance) { (void)instance; }
