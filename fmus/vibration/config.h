/* ToolVibration: variables and modal states are generated from models/vibration.py
 * (model_generated.h); the exact modal update and the outputs are generated too, so the model's
 * hooks are fmus/common/generated_model.c. Nothing else is kept between steps. */
#ifndef CONFIG_H
#define CONFIG_H

#include "model_generated.h"

typedef struct {
    int unused;
} ModelInternal;

#endif
