#include "fmu_instance.h"

#include <float.h>
#include <math.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* Relative tolerance between the importer's communication point and the instance time:
 * importers accumulate t += h or compute t0 + k*h, which differ by rounding only. */
#define TIME_TOLERANCE 1e-9

static const char *state_name(FmuState state) {
    switch (state) {
    case STATE_INSTANTIATED: return "Instantiated";
    case STATE_INITIALIZATION_MODE: return "InitializationMode";
    case STATE_STEP_MODE: return "StepMode";
    case STATE_TERMINATED: return "Terminated";
    case STATE_ERROR: return "Error";
    case STATE_FATAL: return "Fatal";
    }
    return "unknown";
}

static char *copy_string(const char *text) {
    size_t n = strlen(text) + 1;
    char *copy = malloc(n);
    if (copy) memcpy(copy, text, n);
    return copy;
}

void fmu_log_without_instance(FmuLogSink sink, FmuCallback logger, void *environment, const char *name,
                              const char *message) {
    FmuInstance stub;
    if (!sink || !logger) return;
    memset(&stub, 0, sizeof stub);
    stub.name = (char *)(name ? name : "?");
    stub.importer_logger = logger;
    stub.importer_environment = environment;
    sink(&stub, FMU_ERROR, "logStatusError", message);
}

void fmu_log(FmuInstance *instance, FmuStatus status, const char *category, const char *format, ...) {
    va_list args;
    if (!instance->log_sink || !instance->importer_logger) return;
    if (status == FMU_OK && !(instance->logging_on && instance->log_events)) return;
    va_start(args, format);
    vsnprintf(instance->message, sizeof instance->message, format, args);
    va_end(args);
    instance->log_sink(instance, status, category, instance->message);
}

FmuStatus fmu_set_debug_logging(FmuInstance *instance, bool logging_on, size_t n_categories,
                                const char *const categories[]) {
    size_t i;
    if (n_categories > 0 && !categories) {
        fmu_log(instance, FMU_ERROR, "logStatusError", "SetDebugLogging: categories is NULL but nCategories = %zu",
                n_categories);
        return FMU_ERROR;
    }
    instance->logging_on = logging_on;
    instance->log_events = n_categories == 0;
    for (i = 0; i < n_categories; i++) {
        if (!categories[i]) {
            fmu_log(instance, FMU_ERROR, "logStatusError", "SetDebugLogging: category %zu is NULL", i);
            return FMU_ERROR;
        }
        if (strcmp(categories[i], "logEvents") == 0) {
            instance->log_events = true;
        } else if (strcmp(categories[i], "logStatusWarning") != 0 && strcmp(categories[i], "logStatusError") != 0) {
            fmu_log(instance, FMU_WARNING, "logStatusWarning",
                    "SetDebugLogging: unknown log category '%s' (known: logEvents, logStatusWarning, logStatusError)",
                    categories[i]);
        }
    }
    return FMU_OK;
}

static void set_start_values(FmuInstance *instance) {
    memset(&instance->v, 0, sizeof instance->v);
    memset(&instance->internal, 0, sizeof instance->internal);
    model_set_start_values(&instance->v);
    instance->time = 0.0;
    instance->start_time = 0.0;
    instance->stop_time_defined = false;
    instance->stop_time = 0.0;
    instance->outputs_stale = true;
}

/* Where the Float64 outputs lie in ModelVariables, if they fill one run of doubles with nothing else in it. */
static void find_output_run(FmuInstance *instance) {
    size_t i, first = SIZE_MAX, end = 0, count = 0;
    for (i = 0; i < MODEL_VARIABLE_COUNT; i++) {
        const FmuVariable *variable = &MODEL_VARIABLE_TABLE[i];
        if (!variable->name || variable->type != FMU_FLOAT64 || variable->causality != FMU_OUTPUT) continue;
        if (variable->offset < first) first = variable->offset;
        if (variable->offset + variable->count * sizeof(double) > end)
            end = variable->offset + variable->count * sizeof(double);
        count += variable->count;
    }
    if (count > 0 && end - first == count * sizeof(double)) {
        instance->output_run_offset = first;
        instance->output_run_count = count;
    }
}

FmuInstance *fmu_create(const char *function, const char *name, const char *token, const char *resource_path,
                        FmuLogSink sink, FmuCallback logger, void *environment, bool logging_on) {
    FmuInstance *instance;
    char message[512];
    if (!name || name[0] == '\0') {
        snprintf(message, sizeof message, "%s: instanceName must be a non-empty string", function);
        fmu_log_without_instance(sink, logger, environment, "?", message);
        return NULL;
    }
    if (!token || strcmp(token, INSTANTIATION_TOKEN) != 0) {
        snprintf(message, sizeof message,
                 "%s: wrong instantiation token/GUID '%.100s'; this FMU (%s) has '%s': the model description "
                 "and the binary do not belong together",
                 function, token ? token : "(null)", MODEL_IDENTIFIER_STRING, INSTANTIATION_TOKEN);
        fmu_log_without_instance(sink, logger, environment, name, message);
        return NULL;
    }
    instance = calloc(1, sizeof *instance);
    if (!instance) return NULL;
    instance->name = copy_string(name);
    instance->resource_path = copy_string(resource_path ? resource_path : "");
    if (!instance->name || !instance->resource_path) {
        fmu_destroy(instance);
        return NULL;
    }
    instance->log_sink = sink;
    instance->importer_logger = logger;
    instance->importer_environment = environment;
    instance->logging_on = logging_on;
    instance->log_events = true;
    instance->state = STATE_INSTANTIATED;
    find_output_run(instance);
    set_start_values(instance);
#ifdef MODEL_HAS_INSTANTIATE
    if (model_instantiate(instance, function) > FMU_WARNING) {
        fmu_destroy(instance);
        return NULL;
    }
#endif
    fmu_log(instance, FMU_OK, "logEvents", "%s: instance '%s' of %s created", function, name,
            MODEL_IDENTIFIER_STRING);
    return instance;
}

static void free_heap(FmuInstance *instance) {
    free(instance->heap);
    instance->heap = NULL;
    instance->heap_size = 0;
}

FmuStatus fmu_allocate_heap(FmuInstance *instance, const char *function, size_t count) {
    double *heap = count > 0 ? calloc(count, sizeof *heap) : NULL;
    if (count > 0 && !heap) {
        fmu_log(instance, FMU_ERROR, "logStatusError", "%s: out of memory for %zu values (%zu MB)", function, count,
                count * sizeof *heap >> 20);
        return FMU_ERROR;
    }
    free_heap(instance);
    instance->heap = heap;
    instance->heap_size = count;
    return FMU_OK;
}

FmuStatus fmu_resize_heap(FmuInstance *instance, const char *function, size_t count) {
    double *heap;
    if (count == instance->heap_size) return FMU_OK;
    if (!instance->heap || count == 0) return fmu_allocate_heap(instance, function, count); /* nothing to keep */
    heap = count <= SIZE_MAX / sizeof *heap ? realloc(instance->heap, count * sizeof *heap) : NULL;
    if (!heap) { /* the heap is left as it was */
        fmu_log(instance, FMU_ERROR, "logStatusError", "%s: out of memory for %zu values (%zu MB)", function, count,
                count / (((size_t)1 << 20) / sizeof *heap));
        return FMU_ERROR;
    }
    if (count > instance->heap_size)
        memset(heap + instance->heap_size, 0, (count - instance->heap_size) * sizeof *heap);
    instance->heap = heap;
    instance->heap_size = count;
    return FMU_OK;
}

void fmu_destroy(FmuInstance *instance) {
    if (!instance) return;
    model_free_internal(instance);
    free_heap(instance);
    free(instance->name);
    free(instance->resource_path);
    free(instance);
}

FmuStatus fmu_reset(FmuInstance *instance) {
    model_free_internal(instance);
    free_heap(instance);
    set_start_values(instance);
    instance->state = STATE_INSTANTIATED;
#ifdef MODEL_HAS_INSTANTIATE
    return model_instantiate(instance, "Reset");
#else
    return FMU_OK;
#endif
}

FmuStatus fmu_check_state(FmuInstance *instance, const char *function, unsigned allowed_states) {
    if (instance->state & allowed_states) return FMU_OK;
    fmu_log(instance, FMU_ERROR, "logStatusError",
            "%s: illegal call sequence: not allowed in state %s", function, state_name(instance->state));
    return FMU_ERROR;
}

FmuStatus fmu_fail(FmuInstance *instance, FmuStatus status) {
    if (status == FMU_ERROR) instance->state = STATE_ERROR;
    if (status == FMU_FATAL) instance->state = STATE_FATAL;
    return status;
}

FmuStatus fmu_check_arrays(FmuInstance *instance, const char *function, const unsigned int vr[], size_t n_vr,
                           const void *values, size_t n_values) {
    if (n_vr > 0 && !vr) {
        fmu_log(instance, FMU_ERROR, "logStatusError", "%s: valueReferences is NULL but nValueReferences = %zu",
                function, n_vr);
        return FMU_ERROR;
    }
    if (n_values > 0 && !values) {
        fmu_log(instance, FMU_ERROR, "logStatusError", "%s: values is NULL but nValues = %zu", function, n_values);
        return FMU_ERROR;
    }
    if (n_values != n_vr) {
        /* all variables are scalars: one value per value reference */
        fmu_log(instance, FMU_ERROR, "logStatusError",
                "%s: nValues = %zu but nValueReferences = %zu (all variables of %s are scalars)", function,
                n_values, n_vr, MODEL_IDENTIFIER_STRING);
        return FMU_ERROR;
    }
    return FMU_OK;
}

static const char *type_name(FmuType type) {
    switch (type) {
    case FMU_FLOAT64: return "Float64";
    case FMU_INT32: return "Int32";
    case FMU_BOOLEAN: return "Boolean";
    case FMU_STRING: return "String";
    }
    return "unknown";
}

static const char *causality_name(FmuCausality causality) {
    switch (causality) {
    case FMU_INDEPENDENT: return "independent";
    case FMU_PARAMETER: return "parameter";
    case FMU_INPUT: return "input";
    case FMU_OUTPUT: return "output";
    }
    return "unknown";
}

static const FmuVariable *lookup(FmuInstance *instance, const char *function, unsigned int vr, FmuType type) {
    const FmuVariable *variable;
    if (vr >= MODEL_VARIABLE_COUNT) {
        fmu_log(instance, FMU_ERROR, "logStatusError",
                "%s: unknown value reference %u (%s has value references 0..%u)", function, vr,
                MODEL_IDENTIFIER_STRING, MODEL_VARIABLE_COUNT - 1);
        return NULL;
    }
    variable = &MODEL_VARIABLE_TABLE[vr];
    if (!variable->name) {
        fmu_log(instance, FMU_ERROR, "logStatusError",
                "%s: unknown value reference %u: it is an array in the FMI 3 variant of %s; FMI 2 has one "
                "variable per element", function, vr, MODEL_IDENTIFIER_STRING);
        return NULL;
    }
    if (variable->type != type) {
        fmu_log(instance, FMU_ERROR, "logStatusError", "%s: variable '%s' (value reference %u) is %s, not %s",
                function, variable->name, vr, type_name(variable->type), type_name(type));
        return NULL;
    }
    return variable;
}

/* Which variables an importer may set in the instance's current state (FMI 2 and 3 agree here). */
static FmuStatus check_settable(FmuInstance *instance, const char *function, const FmuVariable *variable) {
    bool allowed;
    switch (variable->causality) {
    case FMU_PARAMETER:
        allowed = variable->variability == FMU_TUNABLE
                      ? true
                      : (instance->state & (STATE_INSTANTIATED | STATE_INITIALIZATION_MODE)) != 0;
        break;
    case FMU_INPUT: allowed = true; break;
    default: allowed = false; break;
    }
    if (allowed) return FMU_OK;
    fmu_log(instance, FMU_ERROR, "logStatusError", "%s: variable '%s' (%s) cannot be set in state %s", function,
            variable->name, causality_name(variable->causality), state_name(instance->state));
    return FMU_ERROR;
}

static void refresh_outputs(FmuInstance *instance) {
    if (instance->outputs_stale && instance->state != STATE_INSTANTIATED) {
        model_update_outputs(instance);
        instance->outputs_stale = false;
    }
}

FmuStatus fmu_get_float64(FmuInstance *instance, const char *function, unsigned int vr, double *value) {
    const FmuVariable *variable = lookup(instance, function, vr, FMU_FLOAT64);
    if (!variable) return FMU_ERROR;
    if (vr == VR_time) {
        *value = instance->time;
        return FMU_OK;
    }
    if (variable->causality == FMU_OUTPUT) refresh_outputs(instance);
    memcpy(value, (const char *)&instance->v + variable->offset, sizeof *value);
    return FMU_OK;
}

/* The shortest of %.15g..%.17g that reads back as `value`: the range [0.1, 3] of the model
 * description is reported as written there, not as [0.10000000000000001, 3]; an unbounded side as inf. */
static const char *format_number(char buffer[32], double value) {
    int precision;
    if (value == DBL_MAX || value == -DBL_MAX) return value > 0.0 ? "inf" : "-inf"; /* an unbounded side */
    for (precision = 15; precision < 17; precision++) {
        snprintf(buffer, 32, "%.*g", precision, value);
        if (strtod(buffer, NULL) == value) return buffer;
    }
    snprintf(buffer, 32, "%.17g", value);
    return buffer;
}

/* The name of element `element` of a variable, as the FMI 2 variant names it: name[i,j] with 1-based indices
 * in row-major order (the variable's own name for a scalar). */
static const char *element_name(const FmuVariable *variable, size_t element, char *buffer, size_t size) {
    size_t index[FMU_MAX_RANK], rest = element, used;
    unsigned int d;
    if (variable->rank == 0) return variable->name;
    for (d = variable->rank; d-- > 0;) {
        index[d] = rest % variable->dims[d];
        rest /= variable->dims[d];
    }
    used = (size_t)snprintf(buffer, size, "%s[", variable->name);
    for (d = 0; d < variable->rank && used < size; d++)
        used += (size_t)snprintf(buffer + used, size - used, "%zu%s", index[d] + 1, d + 1 < variable->rank ? "," : "]");
    return buffer;
}

/* NaN, Inf and the range [min, max] of one value of `variable` (element `element` of an array). */
static FmuStatus check_range(FmuInstance *instance, const char *function, const FmuVariable *variable,
                             size_t element, double value) {
    char name[256];
    if (isnan(value) || isinf(value)) {
        fmu_log(instance, FMU_ERROR, "logStatusError", "%s: variable '%s' set to %g: must be a finite number",
                function, element_name(variable, element, name, sizeof name), value);
        return FMU_ERROR;
    }
    if (value < variable->min || value > variable->max) {
        char text[3][32];
        const char *space = variable->unit[0] != '\0' ? " " : ""; /* no stray blanks for unitless variables */
        fmu_log(instance, FMU_ERROR, "logStatusError",
                "%s: variable '%s' = %s%s%s is out of its allowed range [%s, %s]%s%s", function,
                element_name(variable, element, name, sizeof name), format_number(text[0], value), space,
                variable->unit, format_number(text[1], variable->min), format_number(text[2], variable->max), space,
                variable->unit);
        return FMU_ERROR;
    }
    return FMU_OK;
}

FmuStatus fmu_set_float64(FmuInstance *instance, const char *function, unsigned int vr, double value) {
    const FmuVariable *variable = lookup(instance, function, vr, FMU_FLOAT64);
    if (!variable || check_settable(instance, function, variable) != FMU_OK) return FMU_ERROR;
    if (check_range(instance, function, variable, 0, value) != FMU_OK) return FMU_ERROR;
    memcpy((char *)&instance->v + variable->offset, &value, sizeof value);
    instance->outputs_stale = true;
    return FMU_OK;
}

/* An FMI 3 array input or parameter: every element is checked before any is stored, so a rejected call
 * leaves the array as it was. */
static FmuStatus set_float64_array(FmuInstance *instance, const char *function, const FmuVariable *variable,
                                   const double values[]) {
    size_t k;
    if (check_settable(instance, function, variable) != FMU_OK) return FMU_ERROR;
    for (k = 0; k < variable->count; k++)
        if (check_range(instance, function, variable, k, values[k]) != FMU_OK) return FMU_ERROR;
    memcpy((char *)&instance->v + variable->offset, values, variable->count * sizeof(double));
    instance->outputs_stale = true;
    return FMU_OK;
}

FmuStatus fmu_get_int32(FmuInstance *instance, const char *function, unsigned int vr, int32_t *value) {
    const FmuVariable *variable = lookup(instance, function, vr, FMU_INT32);
    if (!variable) return FMU_ERROR;
    if (variable->causality == FMU_OUTPUT) refresh_outputs(instance);
    memcpy(value, (const char *)&instance->v + variable->offset, sizeof *value);
    return FMU_OK;
}

FmuStatus fmu_set_int32(FmuInstance *instance, const char *function, unsigned int vr, int32_t value) {
    const FmuVariable *variable = lookup(instance, function, vr, FMU_INT32);
    if (!variable || check_settable(instance, function, variable) != FMU_OK) return FMU_ERROR;
    if (check_range(instance, function, variable, 0, (double)value) != FMU_OK) return FMU_ERROR;
    memcpy((char *)&instance->v + variable->offset, &value, sizeof value);
    instance->outputs_stale = true;
    return FMU_OK;
}

FmuStatus fmu_get_string(FmuInstance *instance, const char *function, unsigned int vr, const char **value) {
    const FmuVariable *variable = lookup(instance, function, vr, FMU_STRING);
    if (!variable) return FMU_ERROR;
    *value = (const char *)&instance->v + variable->offset;
    return FMU_OK;
}

FmuStatus fmu_set_string(FmuInstance *instance, const char *function, unsigned int vr, const char *value) {
    const FmuVariable *variable = lookup(instance, function, vr, FMU_STRING);
    size_t length;
    if (!variable || check_settable(instance, function, variable) != FMU_OK) return FMU_ERROR;
    if (!value) {
        fmu_log(instance, FMU_ERROR, "logStatusError", "%s: variable '%s' set to NULL: must be a string", function,
                variable->name);
        return FMU_ERROR;
    }
    length = strlen(value);
    if (length >= FMU_STRING_CAPACITY) {
        fmu_log(instance, FMU_ERROR, "logStatusError",
                "%s: variable '%s' set to a string of %zu characters: at most %d are allowed", function,
                variable->name, length, FMU_STRING_CAPACITY - 1);
        return FMU_ERROR;
    }
    memcpy((char *)&instance->v + variable->offset, value, length + 1);
    instance->outputs_stale = true;
    return FMU_OK;
}

FmuStatus fmu_get_boolean(FmuInstance *instance, const char *function, unsigned int vr, bool *value) {
    const FmuVariable *variable = lookup(instance, function, vr, FMU_BOOLEAN);
    if (!variable) return FMU_ERROR;
    if (variable->causality == FMU_OUTPUT) refresh_outputs(instance);
    memcpy(value, (const char *)&instance->v + variable->offset, sizeof *value);
    return FMU_OK;
}

FmuStatus fmu_set_boolean(FmuInstance *instance, const char *function, unsigned int vr, bool value) {
    const FmuVariable *variable = lookup(instance, function, vr, FMU_BOOLEAN);
    if (!variable || check_settable(instance, function, variable) != FMU_OK) return FMU_ERROR;
    memcpy((char *)&instance->v + variable->offset, &value, sizeof value);
    instance->outputs_stale = true;
    return FMU_OK;
}

/* Array forms used by the FMI functions: the standard's checks on the arrays, then one by one. */
/* The number of values the value references stand for (FMI 3 arrays count all their elements),
 * checked against n_values; 0 on an error (logged). */
static size_t count_values(FmuInstance *instance, const char *function, const unsigned int vr[], size_t n_vr,
                           const void *values, size_t n_values) {
    size_t i, total = 0;
    if ((n_vr > 0 && !vr) || (n_values > 0 && !values)) {
        fmu_check_arrays(instance, function, vr, n_vr, values, n_values); /* logs which one is NULL */
        return 0;
    }
    for (i = 0; i < n_vr; i++) {
        const FmuVariable *variable = lookup(instance, function, vr[i], FMU_FLOAT64);
        if (!variable) return 0;
        total += variable->count;
    }
    if (total != n_values) {
        fmu_log(instance, FMU_ERROR, "logStatusError",
                "%s: nValues = %zu but the %zu value references stand for %zu values (arrays count all their "
                "elements)", function, n_values, n_vr, total);
        return 0;
    }
    return total;
}

FmuStatus fmu_get_float64s(FmuInstance *instance, const char *function, const unsigned int vr[], size_t n_vr,
                           double values[], size_t n_values) {
    size_t i, next = 0;
    if (n_vr == 0 && n_values == 0) return FMU_OK;
    if (count_values(instance, function, vr, n_vr, values, n_values) == 0) return FMU_ERROR;
    for (i = 0; i < n_vr; i++) {
        const FmuVariable *variable = &MODEL_VARIABLE_TABLE[vr[i]];
        if (variable->count == 1) {
            if (fmu_get_float64(instance, function, vr[i], &values[next]) != FMU_OK) return FMU_ERROR;
        } else {
            if (variable->causality == FMU_OUTPUT) refresh_outputs(instance);
            memcpy(&values[next], (const char *)&instance->v + variable->offset, variable->count * sizeof(double));
        }
        next += variable->count;
    }
    return FMU_OK;
}

FmuStatus fmu_set_float64s(FmuInstance *instance, const char *function, const unsigned int vr[], size_t n_vr,
                           const double values[], size_t n_values) {
    size_t i, next = 0;
    if (n_vr == 0 && n_values == 0) return FMU_OK;
    if (count_values(instance, function, vr, n_vr, values, n_values) == 0) return FMU_ERROR;
    for (i = 0; i < n_vr; i++) {
        const FmuVariable *variable = &MODEL_VARIABLE_TABLE[vr[i]];
        FmuStatus status = variable->count == 1 ? fmu_set_float64(instance, function, vr[i], values[next])
                                                : set_float64_array(instance, function, variable, &values[next]);
        if (status != FMU_OK) return FMU_ERROR;
        next += variable->count;
    }
    return FMU_OK;
}

FmuStatus fmu_reject_type(FmuInstance *instance, const char *function, const char *type, size_t n_vr) {
    if (n_vr == 0) return FMU_OK;
    fmu_log(instance, FMU_ERROR, "logStatusError", "%s: %s has no variables of type %s", function,
            MODEL_IDENTIFIER_STRING, type);
    return FMU_ERROR;
}

/* The first Float64 output that is NaN or infinite (its value in *value), NULL when all are finite: an FMU
 * never reports success with non-finite results (a step too long for the model's numerics, an overflow). */
static const FmuVariable *non_finite_output(const FmuInstance *instance, double *value) {
    unsigned int i;
    size_t k;
    if (instance->output_run_count > 0) { /* one pass without branches; the table is searched only on a hit */
        const uint64_t exponent = 0x7ff0000000000000u, exponent_one = 0x0010000000000000u;
        const char *run = (const char *)&instance->v + instance->output_run_offset;
        uint64_t any = 0;
        for (k = 0; k < instance->output_run_count; k++) {
            uint64_t bits;
            memcpy(&bits, run + k * sizeof bits, sizeof bits);
            any |= (bits & exponent) + exponent_one; /* carries into the sign bit for Inf and NaN only */
        }
        if (!(any >> 63)) return NULL;
    }
    for (i = 0; i < MODEL_VARIABLE_COUNT; i++) {
        const FmuVariable *variable = &MODEL_VARIABLE_TABLE[i];
        if (!variable->name || variable->type != FMU_FLOAT64 || variable->causality != FMU_OUTPUT) continue;
        for (k = 0; k < variable->count; k++) {
            memcpy(value, (const char *)&instance->v + variable->offset + k * sizeof *value, sizeof *value);
            if (!isfinite(*value)) return variable;
        }
    }
    return NULL;
}

FmuStatus fmu_check_experiment(FmuInstance *instance, const char *function, double start_time,
                               bool stop_time_defined, double stop_time) {
    if (!isfinite(start_time) || (stop_time_defined && (!isfinite(stop_time) || stop_time < start_time))) {
        fmu_log(instance, FMU_ERROR, "logStatusError",
                "%s: bad experiment: startTime = %g, stopTime = %g (must be finite, stopTime >= startTime)",
                function, start_time, stop_time);
        return FMU_ERROR;
    }
    return FMU_OK;
}

FmuStatus fmu_enter_initialization(FmuInstance *instance, const char *function, double start_time,
                                   bool stop_time_defined, double stop_time) {
    if (fmu_check_experiment(instance, function, start_time, stop_time_defined, stop_time) != FMU_OK)
        return FMU_ERROR;
    instance->start_time = start_time;
    instance->time = start_time;
    instance->stop_time_defined = stop_time_defined;
    instance->stop_time = stop_time;
    instance->state = STATE_INITIALIZATION_MODE;
    instance->outputs_stale = true;
    return FMU_OK;
}

FmuStatus fmu_exit_initialization(FmuInstance *instance, const char *function) {
    size_t i;
    FmuStatus status;
    const FmuVariable *bad;
    double output;
    /* Start values may have come from anywhere (an importer that never called set): check all. */
    for (i = 0; i < MODEL_VARIABLE_COUNT; i++) {
        const FmuVariable *variable = &MODEL_VARIABLE_TABLE[i];
        size_t k;
        if (!variable->name) continue;
        if (variable->type == FMU_BOOLEAN || variable->type == FMU_STRING ||
            (variable->causality != FMU_PARAMETER && variable->causality != FMU_INPUT))
            continue;
        for (k = 0; k < variable->count; k++) { /* every element of an FMI 3 array */
            double value;
            if (variable->type == FMU_INT32) {
                int32_t integer;
                memcpy(&integer, (const char *)&instance->v + variable->offset, sizeof integer);
                value = (double)integer;
            } else {
                memcpy(&value, (const char *)&instance->v + variable->offset + k * sizeof(double), sizeof value);
            }
            if (check_range(instance, function, variable, k, value) != FMU_OK) return FMU_ERROR;
        }
    }
    status = model_exit_initialization(instance);
    if (status > FMU_WARNING) return status;
    model_update_outputs(instance);
    instance->outputs_stale = false;
    if ((bad = non_finite_output(instance, &output)) != NULL) {
        fmu_log(instance, FMU_ERROR, "logStatusError", "%s: output '%s' is %g at t = %g s: the model cannot compute "
                "it from these parameters and inputs", function, bad->name, output, instance->time);
        return FMU_ERROR;
    }
    instance->state = STATE_STEP_MODE;
    fmu_log(instance, FMU_OK, "logEvents", "%s: initialized at t = %g s", function, instance->time);
    return status;
}

FmuStatus fmu_do_step(FmuInstance *instance, const char *function, double current_time, double step_size) {
    FmuStatus status;
    const FmuVariable *bad;
    double previous_time, value;
    char text[2][32];
    /* never so loose that a whole (small) step could go unnoticed */
    double tolerance = fmin(TIME_TOLERANCE * fmax(1.0, fabs(instance->time)), 0.25 * fabs(step_size));
    if (!isfinite(step_size) || step_size <= 0.0) {
        fmu_log(instance, FMU_ERROR, "logStatusError", "%s: communicationStepSize = %g s must be > 0 and finite",
                function, step_size);
        return FMU_ERROR;
    }
    if (!isfinite(current_time) || fabs(current_time - instance->time) > tolerance) {
        fmu_log(instance, FMU_ERROR, "logStatusError",
                "%s: currentCommunicationPoint = %s s does not match the instance time %s s", function,
                format_number(text[0], current_time), format_number(text[1], instance->time));
        return FMU_ERROR;
    }
    if (!isfinite(current_time + step_size) || current_time + step_size <= current_time) {
        /* the end of the step would be Inf, or the same number as its start: the time could not advance */
        fmu_log(instance, FMU_ERROR, "logStatusError",
                "%s: a step of %s s from t = %s s does not reach a larger finite time", function,
                format_number(text[0], step_size), format_number(text[1], current_time));
        return FMU_ERROR;
    }
    if (instance->stop_time_defined && current_time + step_size > instance->stop_time + tolerance) {
        fmu_log(instance, FMU_ERROR, "logStatusError", "%s: step to t = %s s goes past stopTime = %s s",
                function, format_number(text[0], current_time + step_size),
                format_number(text[1], instance->stop_time));
        return FMU_ERROR;
    }
    status = model_do_step(instance, current_time, step_size);
    if (status > FMU_WARNING) return status;
    previous_time = instance->time;
    instance->time = current_time + step_size;
    model_update_outputs(instance);
    instance->outputs_stale = false;
    if ((bad = non_finite_output(instance, &value)) != NULL) {
        instance->time = previous_time; /* the last successful time stays the start of the failed step */
        fmu_log(instance, FMU_ERROR, "logStatusError",
                "%s: the step of %s s from t = %s s made output '%s' %g: the model cannot take it (a shorter step "
                "or other inputs may)", function, format_number(text[0], step_size),
                format_number(text[1], current_time), bad->name, value);
        return FMU_ERROR;
    }
    return status;
}

FmuStatus fmu_terminate(FmuInstance *instance, const char *function) {
    FmuStatus status = FMU_OK;
#ifdef MODEL_HAS_TERMINATE
    status = model_terminate(instance, function);
    if (status > FMU_WARNING) return status;
#endif
    instance->state = STATE_TERMINATED;
    fmu_log(instance, FMU_OK, "logEvents", "%s: terminated at t = %g s", function, instance->time);
    return status;
}

/* ---- FMU state snapshots ---- */

#define SNAPSHOT_MAGIC 0x464d5553u /* "FMUS" */

/* A snapshot is one block: this header, then heap_size doubles. Serialization is the block, with a checksum
 * of it so that damaged bytes are rejected instead of restoring a corrupt instance (in memory it is 0). */
struct FmuSnapshot {
    uint32_t magic;
    uint32_t reserved;
    uint64_t bytes;                 /* size of the whole block */
    uint64_t checksum;              /* serialized: FNV-1a 64 of the block with this field 0 */
    char token[64];
    FmuState state;
    double time, start_time, stop_time;
    bool stop_time_defined;
    ModelVariables v;
    ModelInternal internal;
    uint64_t heap_size;
    double heap[];
};

static size_t snapshot_bytes(size_t heap_size) { return sizeof(FmuSnapshot) + heap_size * sizeof(double); }

/* FNV-1a 64 of a serialized snapshot, its checksum field counted as 0. */
static uint64_t snapshot_checksum(const unsigned char *bytes, size_t size) {
    const size_t skip = offsetof(FmuSnapshot, checksum);
    uint64_t h = 0xcbf29ce484222325u;
    size_t i;
    for (i = 0; i < size; i++) h = (h ^ (i - skip < sizeof h ? 0u : bytes[i])) * 0x100000001b3u;
    return h;
}

FmuStatus fmu_get_state(FmuInstance *instance, const char *function, void **snapshot) {
    FmuSnapshot *s;
    size_t bytes = snapshot_bytes(instance->heap_size);
    if (!snapshot) {
        fmu_log(instance, FMU_ERROR, "logStatusError", "%s: FMUstate pointer is NULL", function);
        return FMU_ERROR;
    }
    s = *snapshot;
    if (s && (s->magic != SNAPSHOT_MAGIC)) {
        fmu_log(instance, FMU_ERROR, "logStatusError", "%s: FMUstate was not made by this FMU", function);
        return FMU_ERROR;
    }
    if (!s || s->bytes != bytes) { /* reuse the importer's state in place when the size still fits */
        FmuSnapshot *resized = realloc(s, bytes);
        if (!resized) {
            fmu_log(instance, FMU_ERROR, "logStatusError", "%s: out of memory", function);
            return FMU_ERROR;
        }
        s = resized;
    }
    memset(s, 0, sizeof *s);
    s->magic = SNAPSHOT_MAGIC;
    s->bytes = bytes;
    snprintf(s->token, sizeof s->token, "%s", INSTANTIATION_TOKEN);
    s->state = instance->state;
    s->time = instance->time;
    s->start_time = instance->start_time;
    s->stop_time = instance->stop_time;
    s->stop_time_defined = instance->stop_time_defined;
    s->v = instance->v;
    s->internal = instance->internal;
    s->heap_size = instance->heap_size;
    if (instance->heap_size) memcpy(s->heap, instance->heap, instance->heap_size * sizeof(double));
    *snapshot = s;
    return FMU_OK;
}

static FmuStatus check_snapshot(FmuInstance *instance, const char *function, const FmuSnapshot *s) {
    if (!s) {
        fmu_log(instance, FMU_ERROR, "logStatusError", "%s: FMUstate is NULL", function);
        return FMU_ERROR;
    }
    if (s->magic != SNAPSHOT_MAGIC || strncmp(s->token, INSTANTIATION_TOKEN, sizeof s->token) != 0 ||
        s->bytes != snapshot_bytes(s->heap_size)) {
        fmu_log(instance, FMU_ERROR, "logStatusError",
                "%s: FMUstate was not made by this FMU (%s, token %s)", function, MODEL_IDENTIFIER_STRING,
                INSTANTIATION_TOKEN);
        return FMU_ERROR;
    }
    return FMU_OK;
}

FmuStatus fmu_set_state(FmuInstance *instance, const char *function, const void *snapshot) {
    const FmuSnapshot *s = snapshot;
    if (check_snapshot(instance, function, s) != FMU_OK) return FMU_ERROR;
    if (s->heap_size != instance->heap_size && fmu_allocate_heap(instance, function, s->heap_size) != FMU_OK)
        return FMU_ERROR;
    if (s->heap_size) memcpy(instance->heap, s->heap, s->heap_size * sizeof(double));
    instance->state = s->state;
    instance->time = s->time;
    instance->start_time = s->start_time;
    instance->stop_time = s->stop_time;
    instance->stop_time_defined = s->stop_time_defined;
    instance->v = s->v;
    instance->internal = s->internal;
    instance->outputs_stale = true;
    return FMU_OK;
}

FmuStatus fmu_free_state(FmuInstance *instance, const char *function, void **snapshot) {
    (void)instance;
    (void)function;
    if (snapshot && *snapshot) {
        free(*snapshot);
        *snapshot = NULL;
    }
    return FMU_OK;
}

FmuStatus fmu_serialized_state_size(FmuInstance *instance, const char *function, const void *snapshot,
                                    size_t *size) {
    if (check_snapshot(instance, function, snapshot) != FMU_OK) return FMU_ERROR;
    if (!size) {
        fmu_log(instance, FMU_ERROR, "logStatusError", "%s: size is NULL", function);
        return FMU_ERROR;
    }
    *size = (size_t)((const FmuSnapshot *)snapshot)->bytes;
    return FMU_OK;
}

FmuStatus fmu_serialize_state(FmuInstance *instance, const char *function, const void *snapshot,
                              unsigned char *bytes, size_t size) {
    const FmuSnapshot *s = snapshot;
    if (check_snapshot(instance, function, s) != FMU_OK) return FMU_ERROR;
    if (!bytes || size < s->bytes) {
        fmu_log(instance, FMU_ERROR, "logStatusError", "%s: buffer of %zu bytes is too small (need %zu)", function,
                bytes ? size : 0, (size_t)s->bytes);
        return FMU_ERROR;
    }
    memcpy(bytes, s, (size_t)s->bytes);
    {
        uint64_t checksum = snapshot_checksum(bytes, (size_t)s->bytes);
        memcpy(bytes + offsetof(FmuSnapshot, checksum), &checksum, sizeof checksum);
    }
    return FMU_OK;
}

FmuStatus fmu_deserialize_state(FmuInstance *instance, const char *function, const unsigned char *bytes,
                                size_t size, void **snapshot) {
    FmuSnapshot header, *s;
    if (!bytes || !snapshot || size < sizeof header) {
        fmu_log(instance, FMU_ERROR, "logStatusError",
                "%s: serialized FMUstate has %zu bytes, at least %zu expected (or a NULL pointer was passed)",
                function, size, sizeof header);
        return FMU_ERROR;
    }
    memcpy(&header, bytes, sizeof header);
    header.token[sizeof header.token - 1] = '\0';
    if (check_snapshot(instance, function, &header) != FMU_OK) return FMU_ERROR;
    if (size != header.bytes) {
        fmu_log(instance, FMU_ERROR, "logStatusError", "%s: serialized FMUstate has %zu bytes, expected %zu",
                function, size, (size_t)header.bytes);
        return FMU_ERROR;
    }
    if (header.checksum != snapshot_checksum(bytes, size) || !(header.state & STATES_ANY) ||
        (header.state & (header.state - 1)) != 0) {
        fmu_log(instance, FMU_ERROR, "logStatusError",
                "%s: serialized FMUstate is damaged (its checksum or instance state does not match its bytes)",
                function);
        return FMU_ERROR;
    }
    s = malloc(size);
    if (!s) {
        fmu_log(instance, FMU_ERROR, "logStatusError", "%s: out of memory for a state of %zu bytes", function, size);
        return FMU_ERROR;
    }
    memcpy(s, bytes, size);
    s->checksum = 0;
    if (*snapshot) free(*snapshot);
    *snapshot = s;
    return FMU_OK;
}

FmuStatus fmu_unsupported(FmuInstance *instance, const char *function, const char *why) {
    fmu_log(instance, FMU_ERROR, "logStatusError", "%s: not supported by %s (%s)", function,
            MODEL_IDENTIFIER_STRING, why);
    return FMU_ERROR;
}
