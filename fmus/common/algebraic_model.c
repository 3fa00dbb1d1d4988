/* Model hooks for models whose outputs are algebraic in parameters and inputs (no state between
 * steps): the generated equations are all there is. A model with state writes its own model.c. */
#include "fmu_instance.h"

FmuStatus model_exit_initialization(FmuInstance *instance) {
    (void)instance;
    return FMU_OK;
}

FmuStatus model_do_step(FmuInstance *instance, double time, double step_size) {
    (void)instance, (void)time, (void)step_size;
    return FMU_OK;
}

void model_update_outputs(FmuInstance *instance) { model_evaluate_equations(&instance->v); }

void model_free_internal(FmuInstance *instance) { (void)instance; }
