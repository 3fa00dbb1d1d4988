/* Interpolator: variables are generated from models/interpolator/ (model_generated.h); every output is
 * computed by the engine in interpolator.c from the part program parsed at initialization. The Python
 * reference of the same algorithm is models.interpolator.Interpolator; tests/test_interpolator*.py and the
 * generic FMU tests prove the two equal.
 *
 * The instance heap (fmu_allocate_heap, copied into FMU states) holds, in doubles, the moves, the NURBS
 * curves, the path nodes and intervals and the schedule pieces; InterpLayout gives their offsets. */
#ifndef CONFIG_H
#define CONFIG_H

#include "interpolator.h"
#include "model_generated.h"

typedef struct {
    InterpSettings settings;
    InterpLayout layout;
    InterpState state;
    bool initialized;
} ModelInternal;

#endif
