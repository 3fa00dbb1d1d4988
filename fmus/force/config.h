/* CuttingForce: variables, the spindle-angle update and the force equations are generated from
 * models/cutting_force.py (model_generated.h). This file adds what model.c keeps besides them:
 * the bookkeeping of the displacement history, a ring of `history_size` samples (t, x, y) in the
 * instance heap (fmu_allocate_heap), so FMU states carry it. Flat: copied by value into FMU states. */
#ifndef CONFIG_H
#define CONFIG_H

#include <stddef.h>
#include "model_generated.h"

typedef struct {
    size_t capacity;     /* samples the heap holds now (grows to history_size) */
    size_t count;        /* samples stored, <= capacity */
    size_t next;         /* slot the next sample goes to */
    size_t hint;         /* the sample the last delayed displacement started from (a search hint) */
    bool warned_stopped; /* warned (once) that the spindle is stopped while feeding into the cut */
} ModelInternal;

#endif
