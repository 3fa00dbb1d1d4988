/* MrrEstimator: identifiers, value references and variables are generated from
 * models/mrr_estimator.py (model_generated.h). The model is algebraic: its hooks are
 * fmus/common/generated_model.c and it keeps nothing between steps. */
#ifndef CONFIG_H
#define CONFIG_H

#include "model_generated.h"

typedef struct {
    int unused;
} ModelInternal;

#endif
