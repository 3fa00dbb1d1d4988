/* The compiled stepping loop of the orchestrator's fast path (orchestrator/fastpath.py).
 *
 * Python sets everything up with fmpy (extract, instantiate, parameters, initialization), then
 * describes the co-simulation in the structures below: for each instance its FMI function
 * pointers (taken from fmpy's loaded library) and component, its input and output buffers (the
 * very ctypes arrays the Python path uses), its recorded inputs (channel, interpolation, unit factor;
 * sampled here as orchestrator.recorded does with numpy, see recorded_sample.h) and its links
 * (connections); and the recorded columns. stp_run() then performs ticks
 * [first_tick, last_tick) of the fixed grid exactly as orchestrator/master.py's Python loop does
 * (same FMI calls in the same order, same arithmetic), writing one row per output interval. With a
 * variable communication step ([stepping]) the plan also holds the conditions (gates), which instances are
 * variable, and the state of the coarse intervals, carried from one call to the next. With parameter changes at
 * events ([[on_change]]) it holds the watched outputs: stp_run returns STP_EVENT at the start of a tick where one
 * fires, before anything of that tick, and Python sets the parameters and calls it again from that tick.
 *
 * No global state: everything lives in the caller's structures. The library calls nothing but
 * the FMI functions it is given and, when set, the should_stop callback.
 */
#ifndef MILLING_TWIN_STEPPER_H
#define MILLING_TWIN_STEPPER_H

#include <stddef.h>
#include <stdint.h>

#include "fmi2FunctionTypes.h"
#include "fmi3FunctionTypes.h"

#define STP_ABI_VERSION 7

#if defined(_WIN32)
#define STP_EXPORT __declspec(dllexport)
#elif defined(__GNUC__)
#define STP_EXPORT __attribute__((visibility("default")))
#else
#define STP_EXPORT
#endif

/* Element type of a buffer a link or column reads (STP_BOOL_FMI2: an int, also that of Int32 columns). */
enum { STP_REAL = 0, STP_BOOL_FMI2 = 1, STP_BOOL_FMI3 = 2 };

/* stp_gate.sense: the output's value v against the threshold */
enum {
    STP_ABOVE = 0, /* v > threshold (Real) */
    STP_BELOW = 1, /* v < threshold (Real) */
    STP_IS = 2     /* (v != 0) == (threshold != 0) (Boolean) */
};

/* stp_outcome.code */
enum {
    STP_DONE = 0,       /* reached last_tick */
    STP_STOPPED = 1,    /* should_stop returned nonzero after an output row: stopped after that tick */
    STP_TERMINATED = 2, /* an FMI 3 instance set terminateSimulation: stopped after that tick */
    STP_FAILED = 3,     /* an FMI call returned Discard, Error or Fatal */
    STP_OUT_OF_RECORDING = 4, /* a recorded input was due at a time outside the recording (with its tolerance) */
    STP_EVENT = 5       /* an [[on_change]] entry fires at the start of tick `tick`: nothing of it was done */
};

/* stp_outcome.function */
enum {
    STP_FN_NONE = 0, STP_FN_SET_REAL, STP_FN_SET_BOOLEAN, STP_FN_DO_STEP, STP_FN_GET_REAL, STP_FN_GET_BOOLEAN,
    STP_FN_GET_INTEGER
};

/* One connection into an instance's input buffer. */
typedef struct {
    const void *source; /* an element of the source's output buffer, or of its copy from the tick's start (delay) */
    double factor;      /* reals: input = source * factor */
    int32_t source_kind; /* STP_REAL, STP_BOOL_FMI2, STP_BOOL_FMI3 */
    int32_t position;   /* index into the target's real_in or bool_in */
} stp_link;

/* One recorded input of an instance: a channel of the plan's recording. */
typedef struct {
    const double *values; /* the channel, one value per recorded time (a boolean channel as 0.0 / 1.0, or
                             the column a threshold channel compares) */
    double factor;        /* reals: input = value * factor (the unit factor); booleans with linear = 1: the
                             threshold the interpolated column must exceed */
    int64_t hint;         /* search position between calls (recorded_sample.h); start at 0 */
    int32_t linear;       /* 1: linear interpolation, 0: hold (booleans: 1 = a threshold channel's crossing) */
    int32_t reserved;
} stp_recorded;

/* One condition of the variable communication step: a gate instance's output against a threshold. */
typedef struct {
    const void *source; /* an element of the gate instance's output buffer (read after each of its steps) */
    double threshold;   /* in the output's unit; STP_IS: nonzero = true */
    int32_t kind;       /* STP_REAL, STP_BOOL_FMI2, STP_BOOL_FMI3 */
    int32_t sense;      /* STP_ABOVE, STP_BELOW, STP_IS */
} stp_gate;

/* One [[on_change]] entry: its watched output, checked at the start of each tick k % ticks_per_step == 0. It fires
 * when the value differs from `last` and equals `equals`. */
typedef struct {
    const void *source;     /* an element of the instance's output buffer (read after each of its steps) */
    int64_t ticks_per_step; /* the instance's step in ticks: its communication points */
    int32_t kind;           /* STP_BOOL_FMI2 (an int: an Int32 or an FMI 2 Boolean) or STP_BOOL_FMI3 */
    int32_t boolean;        /* 1: a Boolean output, its value taken as 0 or 1 */
    int32_t equals;         /* the value that fires */
    int32_t last;           /* the value at the previous check (Python sets it after initialization and events) */
} stp_watch;

/* One recorded column (after "time"). */
typedef struct {
    const void *source;
    int32_t kind;
    int32_t reserved;
} stp_column;

typedef struct {
    void *component;
    /* FMI 2 functions (fmi_version 2) ... */
    fmi2SetRealTYPE *fmi2_set_real;
    fmi2SetBooleanTYPE *fmi2_set_boolean;
    fmi2GetRealTYPE *fmi2_get_real;
    fmi2GetBooleanTYPE *fmi2_get_boolean;
    fmi2DoStepTYPE *fmi2_do_step;
    /* ... or FMI 3 functions (fmi_version 3) */
    fmi3SetFloat64TYPE *fmi3_set_float64;
    fmi3SetBooleanTYPE *fmi3_set_boolean;
    fmi3GetFloat64TYPE *fmi3_get_float64;
    fmi3GetBooleanTYPE *fmi3_get_boolean;
    fmi3DoStepTYPE *fmi3_do_step;

    /* Inputs, set before each step: real_in = [recorded reals..., linked reals...], likewise bool_in
     * (fmi2Boolean or fmi3Boolean elements by fmi_version). */
    const uint32_t *vr_real_in;
    const uint32_t *vr_bool_in;
    double *real_in;
    void *bool_in;
    /* The recorded inputs, sampled at each step's time: the first n_rec_real of real_in, the first
     * n_rec_bool of bool_in (true where the sample is nonzero). */
    stp_recorded *rec_real;
    stp_recorded *rec_bool;
    const stp_link *real_links;
    const stp_link *bool_links;

    /* Outputs: what connections read and what is recorded; *_prev: copies at the tick's start. */
    const uint32_t *vr_real_out;
    const uint32_t *vr_bool_out;
    double *real_out;
    double *real_prev;
    void *bool_out;
    void *bool_prev;

    int64_t n_real_in, n_bool_in;       /* totals, recorded included */
    int64_t n_rec_real, n_rec_bool;     /* the first n_rec_* inputs come from rec_* */
    int64_t n_real_links, n_bool_links;
    int64_t n_real_out, n_bool_out;

    int32_t fmi_version;      /* 2 or 3 */
    int32_t ticks_per_step;   /* due at ticks k with k % ticks_per_step == 0 */
    int32_t get_after_step;   /* outputs feed connections, gates or watches: read right after each step */
    int32_t snapshot;         /* source of a delayed connection: copy outputs at each tick's start */
    int32_t get_at_rows;      /* has outputs: read them at each output row */
    int32_t variable;         /* a variable instance of [stepping]: one step per coarse interval while coarse */

    /* Int32 outputs (recorded or watched by [[on_change]]; fmi2Integer or fmi3Int32 elements, both int32) */
    fmi2GetIntegerTYPE *fmi2_get_integer;
    fmi3GetInt32TYPE *fmi3_get_int32;
    const uint32_t *vr_int_out;
    int32_t *int_out;
    int64_t n_int_out;

    /* Value references of each buffer: as many as its values, but one for a whole FMI 3 array (its values
     * follow each other in the buffer, in order); FMI 2 arrays are scalars. */
    int64_t n_vr_real_in, n_vr_bool_in, n_vr_real_out, n_vr_bool_out, n_vr_int_out;
} stp_instance;

typedef int (*stp_should_stop)(double time);

typedef struct {
    double start;             /* t_k = start + k * base */
    double base;
    int64_t n_ticks;          /* N: the run ends at t_N */
    int64_t ticks_per_output; /* a row after each tick k with (k + 1) % ticks_per_output == 0 */
    int64_t n_instances;      /* in execution order */
    int64_t n_columns;
    stp_instance *instances;
    const stp_column *columns;
    stp_should_stop should_stop; /* NULL, or asked after each row: nonzero stops after that tick */
    /* The recording the recorded inputs sample (NULL and 0 without any): strictly increasing times, and
     * how far beyond its ends a time may lie (orchestrator.recorded.RecordedData.at: 1e-9 of the duration). */
    const double *recorded_time;
    int64_t recorded_samples;
    double recorded_tolerance;
    /* The variable communication step ([stepping]; n_gates 0: none, nothing below is used). At each tick
     * k % ticks_per_interval == 0, before instance first_variable, the gates are evaluated: the interval
     * [k, k + ticks_per_interval) is fine if one holds now or held at one of the hold_intervals evaluations
     * before. */
    const stp_gate *gates;
    int64_t n_gates;
    int64_t ticks_per_interval; /* M = coarse_step / base */
    int64_t first_variable;     /* index of the first variable instance in execution order */
    int64_t hold_intervals;     /* H >= 1 ([stepping].hold in coarse intervals) */
    /* State carried from call to call (start with fine = 1, hold_left = 0, counts 0); stp_run updates it. */
    int64_t fine_intervals;     /* intervals evaluated fine */
    int64_t coarse_intervals;   /* intervals evaluated coarse */
    int64_t variable_steps;     /* doSteps of the variable instances */
    int64_t hold_left;          /* evaluations still fine after the latest because a condition held */
    int32_t fine;               /* the current interval is fine */
    /* [[on_change]] (n_watches 0: none). At a tick's start the due watches are checked: when one fires, stp_run
     * returns STP_EVENT at that tick, the watches unchanged; else each due watch remembers its value. */
    stp_watch *watches;
    int64_t n_watches;
} stp_plan;

typedef struct {
    int64_t tick;       /* ticks completed: the grid index reached */
    int64_t rows;       /* rows written */
    int32_t code;       /* STP_DONE ... STP_EVENT */
    int32_t instance;   /* index of the failing or terminating instance, else -1 */
    int32_t function;   /* STP_FN_* of the failing call; STP_OUT_OF_RECORDING: 0 (all inputs sample one recording) */
    int32_t status;     /* its FMI status */
    double time;        /* master time of the failing call / start of the terminating step / sampled time /
                           the event's tick */
} stp_outcome;

/* STP_ABI_VERSION of the library. */
STP_EXPORT int stp_abi_version(void);

/* sizeof of stp_link (0), stp_column (1), stp_instance (2), stp_plan (3), stp_outcome (4), stp_recorded (5),
 * stp_gate (6), stp_watch (7); 0 otherwise. */
STP_EXPORT size_t stp_struct_size(int which);

/* Ticks [first_tick, last_tick) (last_tick <= plan->n_ticks). rows: room for one row of
 * 1 + n_columns doubles (time first) per output row in that range. */
STP_EXPORT void stp_run(stp_plan *plan, int64_t first_tick, int64_t last_tick, double *rows,
                        stp_outcome *outcome);

#endif
