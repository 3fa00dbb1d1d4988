/* CuttingForce: variables, the spindle-angle update and the force equations are generated from
 * models/cutting_force.py (model_generated.h). This file adds what model.c keeps besides them:
 * the bookkeeping of the displacement history (fmus/common/displacement_history.h), a ring of
 * `history_size` samples (t, x, y) in the instance heap, so FMU states carry it. Flat: copied by value
 * into FMU states. */
#ifndef CONFIG_H
#define CONFIG_H

#include <stdbool.h>
#include "displacement_history.h"
#include "step_clock.h"
#include "model_generated.h"

typedef struct {
    DisplacementHistory history; /* the ring in the instance heap (from its start) */
    StepClock clock;             /* the time since the start that the angle and the history advance by */
    bool warned_stopped;         /* warned (once) that the spindle is stopped while feeding into the cut */
} ModelInternal;

#endif
