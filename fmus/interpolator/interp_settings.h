/* The engine's settings from the FMU's variables (ModelVariables of model_generated.h, generated from
 * models/interpolator/definition.py): the FMU (model.c) converts its parameters with interp_settings_of; the
 * standalone tools (interp_run, the fuzz harness) start from interp_default_settings, the parameters' start
 * values of the model definition (model_set_start_values of model_generated.c). */
#ifndef INTERP_SETTINGS_H
#define INTERP_SETTINGS_H

#include "interpolator.h"
#include "model_generated.h"

void interp_settings_of(const ModelVariables *v, InterpSettings *s);
/* DIALECT_FANUC, DIALECT_LINUXCNC or DIALECT_SINUMERIK for the `dialect` parameter's value; -1 for another. */
int interp_dialect(const char *name);
/* The settings of the model definition's defaults (every parameter at its start value). */
void interp_default_settings(InterpSettings *s);

#endif
