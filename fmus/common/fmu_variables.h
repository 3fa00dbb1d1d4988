/* The variable table: what the generic FMI wrapper knows of a model's variables.
 * Each model's table is generated from its definition in models/ (see models/codegen.py). */
#ifndef FMU_VARIABLES_H
#define FMU_VARIABLES_H

#include <stddef.h>

typedef enum { FMU_FLOAT64, FMU_INT32, FMU_BOOLEAN, FMU_STRING } FmuType;
typedef enum { FMU_INDEPENDENT, FMU_PARAMETER, FMU_INPUT, FMU_OUTPUT } FmuCausality;
typedef enum { FMU_FIXED, FMU_TUNABLE, FMU_CONTINUOUS, FMU_DISCRETE } FmuVariability;

typedef struct {
    unsigned int vr;            /* equals the row's index in the table */
    const char *name;
    FmuType type;
    FmuCausality causality;
    FmuVariability variability;
    size_t offset;              /* of the (first) value in ModelVariables */
    size_t count;               /* number of values: 1, or the elements of an FMI 3 array */
    double min, max;            /* allowed range (Float64, Int32), checked on every set and at initialization */
    const char *unit;
} FmuVariable;

#endif
