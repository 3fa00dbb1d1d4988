/* The variable table: what the generic FMI wrapper knows of a model's variables.
 * Each model's table is generated from its definition in models/ (see models/codegen.py). */
#ifndef FMU_VARIABLES_H
#define FMU_VARIABLES_H

#include <stddef.h>

typedef enum { FMU_FLOAT64, FMU_INT32, FMU_BOOLEAN, FMU_STRING } FmuType;
typedef enum { FMU_INDEPENDENT, FMU_PARAMETER, FMU_INPUT, FMU_OUTPUT } FmuCausality;
typedef enum { FMU_FIXED, FMU_TUNABLE, FMU_CONTINUOUS, FMU_DISCRETE } FmuVariability;

#define FMU_MAX_RANK 4 /* dimensions of an FMI 3 array (models/codegen.py FMU_MAX_RANK) */

typedef struct {
    unsigned int vr;            /* equals the row's index in the table */
    const char *name;
    FmuType type;
    FmuCausality causality;
    FmuVariability variability;
    size_t offset;              /* of the (first) value in ModelVariables */
    size_t count;               /* number of values: 1, or the elements of an FMI 3 array (Float64 only) */
    double min, max;            /* allowed range (Float64, Int32), checked on every set and at initialization;
                                 * -DBL_MAX/DBL_MAX for an unbounded side (INFINITY is no constant under MSVC) */
    const char *unit;
    unsigned int rank;          /* FMI 3 arrays: number of dimensions (0 for scalars and FMI 2 elements) */
    unsigned int dims[FMU_MAX_RANK]; /* their sizes, row-major: the element names in messages are name[i,j] */
} FmuVariable;

#endif
