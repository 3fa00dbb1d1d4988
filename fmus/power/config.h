/* SpindlePower: identifiers, value references and variables are generated from models/power.py
 * (model_generated.h); this file adds what the model keeps besides its variables. */
#ifndef CONFIG_H
#define CONFIG_H

#include "model_generated.h"

typedef struct {
    /* warned once that material is removed while the spindle is stopped (a data or wiring error) */
    bool warned_cutting_without_spindle;
} ModelInternal;

#endif
