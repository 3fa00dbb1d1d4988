/* The FMI-version-independent core of every FMU: instance lifetime, the call-sequence state
 * machine, checked access to variables through the generated variable table, FMU state
 * snapshots and logging. fmi2_api.c and fmi3_api.c map the standard's functions onto it;
 * a model only supplies the hooks at the end of this file (its model.c). */
#ifndef FMU_INSTANCE_H
#define FMU_INSTANCE_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>
#include "config.h"

typedef enum { FMU_OK = 0, FMU_WARNING = 1, FMU_DISCARD = 2, FMU_ERROR = 3, FMU_FATAL = 4 } FmuStatus;

/* Instance states, as bits so a function's allowed states are one mask. */
typedef enum {
    STATE_INSTANTIATED = 1 << 0,
    STATE_INITIALIZATION_MODE = 1 << 1,
    STATE_STEP_MODE = 1 << 2,      /* FMI 2: slaveInitialized (step complete); FMI 3: Step Mode */
    STATE_TERMINATED = 1 << 3,
    STATE_ERROR = 1 << 4,          /* a call returned Error: only reset, free, get and FMU state calls */
    STATE_FATAL = 1 << 5
} FmuState;

#define STATES_ANY (STATE_INSTANTIATED | STATE_INITIALIZATION_MODE | STATE_STEP_MODE | STATE_TERMINATED | STATE_ERROR)
#define STATES_GET (STATE_INITIALIZATION_MODE | STATE_STEP_MODE | STATE_TERMINATED | STATE_ERROR)
#define STATES_SET (STATE_INSTANTIATED | STATE_INITIALIZATION_MODE | STATE_STEP_MODE)

typedef struct FmuInstance FmuInstance;

/* The importer's logger, stored as a generic function pointer (ISO C forbids object pointers). */
typedef void (*FmuCallback)(void);

/* Forwards one finished message to the importer's logger (FMI-version specific). */
typedef void (*FmuLogSink)(const FmuInstance *instance, FmuStatus status, const char *category, const char *message);

struct FmuInstance {
    char *name;
    char *resource_path;
    FmuLogSink log_sink;
    FmuCallback importer_logger;     /* the importer's callback, called by log_sink */
    void *importer_environment;
    bool logging_on;
    bool log_events;                /* category logEvents enabled */
    FmuState state;
    double time;
    double start_time;
    bool stop_time_defined;
    double stop_time;
    bool outputs_stale;             /* inputs or parameters changed since outputs were computed */
    ModelVariables v;
    ModelInternal internal;         /* model state that is not a variable (config.h), flat */
    double *heap;                   /* model data sized at initialization (fmu_allocate_heap) */
    size_t heap_size;               /* number of doubles in heap */
    char message[1024];             /* scratch for formatting log messages; per instance, no globals */
    /* the Float64 outputs, when they are one run of doubles in v (from the variable table, at creation;
     * count 0 when they are not): the check for non-finite outputs after every step reads just those */
    size_t output_run_offset, output_run_count;
    /* what the CPU this process runs on offers, for a model to pick a kernel by (ForceNet: AVX2), set by the
     * model's instantiate hook; not part of FMU states (they copy v, internal and the heap), so a state
     * serialized on another machine and restored here keeps this machine's */
    unsigned cpu_features;
};

/* Lifetime. */
FmuInstance *fmu_create(const char *function, const char *name, const char *token, const char *resource_path,
                        FmuLogSink sink, FmuCallback logger, void *environment, bool logging_on);
void fmu_destroy(FmuInstance *instance);
FmuStatus fmu_reset(FmuInstance *instance);

/* Logging: errors and warnings always reach the importer; events only with debug logging on. */
void fmu_log(FmuInstance *instance, FmuStatus status, const char *category, const char *format, ...)
#if defined(__GNUC__)
    __attribute__((format(printf, 4, 5)))
#endif
    ;
void fmu_log_without_instance(FmuLogSink sink, FmuCallback logger, void *environment, const char *name,
                              const char *message);
FmuStatus fmu_set_debug_logging(FmuInstance *instance, bool logging_on, size_t n_categories,
                                const char *const categories[]);

/* Returns FMU_OK if `function` may be called in the instance's state, else logs
 * "<function>: illegal call sequence ..." and returns FMU_ERROR. */
FmuStatus fmu_check_state(FmuInstance *instance, const char *function, unsigned allowed_states);
/* Remember an Error: afterwards only reset, free, get and FMU-state calls are allowed. */
FmuStatus fmu_fail(FmuInstance *instance, FmuStatus status);
FmuStatus fmu_check_arrays(FmuInstance *instance, const char *function, const unsigned int vr[], size_t n_vr,
                           const void *values, size_t n_values);

/* Checked access to one variable; `function` names the FMI call in messages. */
FmuStatus fmu_get_float64(FmuInstance *instance, const char *function, unsigned int vr, double *value);
FmuStatus fmu_set_float64(FmuInstance *instance, const char *function, unsigned int vr, double value);
FmuStatus fmu_get_int32(FmuInstance *instance, const char *function, unsigned int vr, int32_t *value);
FmuStatus fmu_set_int32(FmuInstance *instance, const char *function, unsigned int vr, int32_t value);
FmuStatus fmu_get_boolean(FmuInstance *instance, const char *function, unsigned int vr, bool *value);
/* Strings live in ModelVariables (FMU_STRING_CAPACITY bytes each); get returns a pointer to it. */
FmuStatus fmu_get_string(FmuInstance *instance, const char *function, unsigned int vr, const char **value);
FmuStatus fmu_set_string(FmuInstance *instance, const char *function, unsigned int vr, const char *value);
FmuStatus fmu_set_boolean(FmuInstance *instance, const char *function, unsigned int vr, bool value);
FmuStatus fmu_get_float64s(FmuInstance *instance, const char *function, const unsigned int vr[], size_t n_vr,
                           double values[], size_t n_values);
FmuStatus fmu_set_float64s(FmuInstance *instance, const char *function, const unsigned int vr[], size_t n_vr,
                           const double values[], size_t n_values);
FmuStatus fmu_reject_type(FmuInstance *instance, const char *function, const char *type_name, size_t n_vr);

/* Mode changes. An experiment needs a finite startTime and, when defined, a finite stopTime >= startTime
 * (fmu_check_experiment logs and returns Error otherwise; fmu_enter_initialization checks it too). */
FmuStatus fmu_check_experiment(FmuInstance *instance, const char *function, double start_time,
                               bool stop_time_defined, double stop_time);
FmuStatus fmu_enter_initialization(FmuInstance *instance, const char *function, double start_time,
                                   bool stop_time_defined, double stop_time);
FmuStatus fmu_exit_initialization(FmuInstance *instance, const char *function);
FmuStatus fmu_do_step(FmuInstance *instance, const char *function, double current_time, double step_size);
FmuStatus fmu_terminate(FmuInstance *instance, const char *function);

/* FMU state snapshots (rollback) and their serialization. */
typedef struct FmuSnapshot FmuSnapshot;
FmuStatus fmu_get_state(FmuInstance *instance, const char *function, void **snapshot);
FmuStatus fmu_set_state(FmuInstance *instance, const char *function, const void *snapshot);
FmuStatus fmu_free_state(FmuInstance *instance, const char *function, void **snapshot);
FmuStatus fmu_serialized_state_size(FmuInstance *instance, const char *function, const void *snapshot,
                                    size_t *size);
FmuStatus fmu_serialize_state(FmuInstance *instance, const char *function, const void *snapshot,
                              unsigned char *bytes, size_t size);
FmuStatus fmu_deserialize_state(FmuInstance *instance, const char *function, const unsigned char *bytes,
                                size_t size, void **snapshot);

FmuStatus fmu_unsupported(FmuInstance *instance, const char *function, const char *why);

/* Model data whose size is known only at initialization (a grid, a history buffer): `count`
 * doubles, zeroed, owned by the instance, copied into FMU states and their serialization. */
FmuStatus fmu_allocate_heap(FmuInstance *instance, const char *function, size_t count);
/* The heap resized to `count` doubles, its first min(count, old size) kept and the rest zeroed (a model whose
 * data changes size mid-run: the Workpiece's tool tables at a tool change). On failure it logs and returns
 * FMU_ERROR, the heap unchanged. */
FmuStatus fmu_resize_heap(FmuInstance *instance, const char *function, size_t count);

/* ---- Hooks each model implements in its model.c ---- */

/* After parameters and start values are set and range-checked: model-specific checks
 * (log the variable and the problem, return FMU_ERROR) and setup of ModelInternal. */
FmuStatus model_exit_initialization(FmuInstance *instance);
/* Advance the model's internal state over [time, time + step_size]. */
FmuStatus model_do_step(FmuInstance *instance, double time, double step_size);
/* Compute outputs from the current parameters, inputs and internal state. */
void model_update_outputs(FmuInstance *instance);
/* Release what ModelInternal owns (on reset and free). FMU states copy ModelInternal by value:
 * memory a model needs belongs in the instance heap (fmu_allocate_heap), not behind pointers. */
void model_free_internal(FmuInstance *instance);

/* Optional: a model whose config.h defines MODEL_HAS_INSTANTIATE implements this hook, called when the
 * instance is created (start values set, logger installed) and again by reset (which returns to that
 * state), e.g. to load data from instance->resource_path into the heap. `function` names the FMI call for
 * messages. An Error (logged by the hook) makes instantiation return NULL and reset return Error. */
#ifdef MODEL_HAS_INSTANTIATE
FmuStatus model_instantiate(FmuInstance *instance, const char *function);
#endif

/* Optional: a model whose config.h defines MODEL_HAS_TERMINATE implements this hook, called by Terminate
 * (`function` names the FMI call for messages), e.g. to write a result file. An Error (logged by the hook)
 * makes Terminate return Error. */
#ifdef MODEL_HAS_TERMINATE
FmuStatus model_terminate(FmuInstance *instance, const char *function);
#endif

#endif
