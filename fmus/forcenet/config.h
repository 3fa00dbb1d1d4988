/* ForceNet: variables, the spindle-angle update, spindle_angle and feed_per_tooth are generated from
 * models/force_net.py (model_generated.h); model.c computes the forces with the network of forcenet.c.
 *
 * The instance heap (fmu_allocate_heap, copied into FMU states) holds the network's parameters, loaded from
 * resources/weights.bin when the instance is created (model_instantiate, the wrapper's optional hook, also
 * run on reset): per layer its weights transposed (in x out) and its biases, at the offsets of `net`; after
 * them, from the end of initialization, the displacement history of the regenerative chip
 * (fmus/common/displacement_history.h, as CuttingForce keeps it).
 * The step clock (fmus/common/step_clock.h) is the time since the start that the spindle angle and the history
 * advance by. */
#ifndef CONFIG_H
#define CONFIG_H

#include <stdbool.h>
#include "displacement_history.h"
#include "forcenet.h"
#include "step_clock.h"
#include "model_generated.h"

#define MODEL_HAS_INSTANTIATE 1 /* fmu_instance.h: model_instantiate loads the weights */

typedef struct {
    ForceNetLayout net; /* sizes, scales and heap offsets of the loaded network */
    DisplacementHistory history; /* the regenerative chip's history ring, in the heap after the network */
    StepClock clock;    /* the time since the start of the run that the model has advanced by */
    bool loaded;        /* the heap holds a network (false only after a failed reset) */
    bool warned_stopped; /* warned (once) that the spindle is stopped while feeding into the cut */
} ModelInternal;

#endif
