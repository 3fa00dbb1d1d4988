/* Fuzz harness of the FMI entry points (libFuzzer entry point; tests/fuzz/README.md). Compiled once per FMU
 * and FMI version (FMI_VERSION = 2 or 3) together with that FMU's sources and generated variable table, so
 * the FMU code is instrumented and the harness knows every variable (type, causality, range).
 *
 * The input is a program of FMI calls: each call is one opcode byte followed by the bytes its arguments take
 * (value references, values from a table of special ones -- NaN, +-Inf, +-DBL_MAX, 0, -0, the variable's
 * bounds and just outside them, denormals -- or raw, strings, step sizes, state slots). The harness keeps its
 * own model of the FMU's state (Instantiated, InitializationMode, StepMode, Terminated, Error) written from
 * the FMI 2.0 / 3.0 co-simulation state machines, and aborts (a finding) when:
 * - a call not allowed in the current state, or with an invalid argument (unknown value reference, wrong
 *   type, not settable, non-finite or out of range value, too long or NULL string, wrong nValues, bad
 *   experiment, communication point not the instance time, step size <= 0 or non-finite, step past stopTime,
 *   NULL pointers), does not return Error; a valid set or get does not return OK;
 * - a call returns Error without logging a message with status Error, or returns Fatal, Discard or Pending;
 * - after Error only reset, free, get and FMU-state calls are accepted (the others must return Error);
 * - a get returns something else than what was set, or than the instance time;
 * - after an OK doStep or exitInitializationMode a Float64 variable is NaN or infinite;
 * - restoring an FMU state (directly or through serialize + deserialize) does not restore every Float64 value
 *   and the time; a serialized state with a byte changed is not rejected;
 * and of course on any AddressSanitizer / UBSan report, leak or crash. */
#define _POSIX_C_SOURCE 200809L
#include <float.h>
#include <math.h>
#include <stdarg.h>
#include <stdbool.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "model_generated.h"

#if FMI_VERSION == 2
#include "fmi2Functions.h"
#else
#include "fmi3Functions.h"
#endif

#ifndef FUZZ_RESOURCES
#define FUZZ_RESOURCES "" /* the model's resources/ folder (absolute), "" when it has none */
#endif

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

#define REQUIRE(condition, ...)                                                                              \
    do {                                                                                                     \
        if (!(condition)) {                                                                                  \
            fprintf(stderr, "fuzz_fmi (%s, FMI %d) line %d: ", MODEL_IDENTIFIER_STRING, FMI_VERSION, __LINE__); \
            fprintf(stderr, __VA_ARGS__);                                                                    \
            fprintf(stderr, "\n");                                                                           \
            abort();                                                                                         \
        }                                                                                                    \
    } while (0)

enum { S_NONE, S_INSTANTIATED, S_INIT, S_STEP, S_TERMINATED, S_ERROR };
static const char *const STATE_NAMES[] = {"none", "Instantiated", "InitializationMode", "StepMode", "Terminated",
                                          "Error"};
#define IN(state, mask) (((mask) >> (state)) & 1u)
#define M(state) (1u << (state))
#define ANY (M(S_INSTANTIATED) | M(S_INIT) | M(S_STEP) | M(S_TERMINATED) | M(S_ERROR))
#define GETS (M(S_INIT) | M(S_STEP) | M(S_TERMINATED) | M(S_ERROR))
#define SETS (M(S_INSTANTIATED) | M(S_INIT) | M(S_STEP))

#define SLOTS 3
#define MAX_VR 6
#define MAX_ELEMENTS 256 /* elements of the largest array variable set at once (ForceNet's 8 x 24 map: 192) */
#define STATUS_OK 0
#define STATUS_WARNING 1
#define STATUS_DISCARD 2
#define STATUS_ERROR 3

/* What the harness knows of the Float64 values (scalars and array elements, in table order) and of the values
 * it set (a shadow per value reference). */
typedef struct {
    bool known[256];
    double value[256];
} Shadow;

typedef struct {
    void *state;       /* the FMU's state object, or NULL */
    int harness_state; /* our state when it was taken */
    double time, stop, setup_start, setup_stop;
    bool stop_defined, setup_stop_defined;
    bool have_values;
    double *values; /* every Float64 value when it was taken (when gettable) */
    Shadow shadow;
} Slot;

typedef struct {
    const uint8_t *data;
    size_t size, pos;
#if FMI_VERSION == 2
    fmi2Component c;
    fmi2CallbackFunctions callbacks;
    double setup_start, setup_stop;
    bool setup_stop_defined;
#else
    fmi3Instance c;
#endif
    int state;
    double time;
    bool stop_defined;
    double stop;
    Shadow shadow;
    Slot slots[SLOTS];
    size_t n_values; /* Float64 values: sum of the counts */
    double *scratch;
    unsigned errors_logged; /* log messages with status Error since the last call started */
    bool trace;             /* $FUZZ_FMI_TRACE set: every call and its status on stderr (reading a finding) */
    char name[32];
} Harness;

/* ---- reading the input ---- */

static bool more(const Harness *h) { return h->pos < h->size; }
static uint8_t u8(Harness *h) { return h->pos < h->size ? h->data[h->pos++] : 0; }
static uint32_t u32(Harness *h) {
    uint32_t v = 0;
    int i;
    for (i = 0; i < 4; i++) v = v << 8 | u8(h);
    return v;
}
static double raw64(Harness *h) {
    uint64_t bits = 0;
    double v;
    int i;
    for (i = 0; i < 8; i++) bits = bits << 8 | u8(h);
    memcpy(&v, &bits, sizeof v);
    return v;
}

/* A value for a variable with bounds [lo, hi]: mostly inside (the simulation goes on), else special. */
static double pick_value(Harness *h, double lo, double hi) {
    uint8_t k = u8(h);
    /* an unbounded side is -DBL_MAX/DBL_MAX in the variable table */
    double a = lo > -DBL_MAX ? lo : -1e3, b = hi < DBL_MAX ? hi : 1e3, f = u8(h) / 255.0;
    switch (k % 24) {
    case 0: return NAN;
    case 1: return INFINITY;
    case 2: return -INFINITY;
    case 3: return DBL_MAX;
    case 4: return -DBL_MAX;
    case 5: return 0.0;
    case 6: return -0.0;
    case 7: return lo;
    case 8: return hi;
    case 9: return nextafter(lo, -INFINITY);
    case 10: return nextafter(hi, INFINITY);
    case 11: return 4.9e-324;
    case 12: return raw64(h);
    case 13: return 1e300 * (f - 0.5);
    case 14: return -1.0;
    case 15: return 1.0;
    default: return a + (b - a) * f;
    }
}

/* A value reference: mostly a real one, sometimes past the table or huge. */
static unsigned int pick_vr(Harness *h) {
    uint8_t k = u8(h);
    if (k == 255) return 0xFFFFFFFFu;
    return k % (MODEL_VARIABLE_COUNT + 2);
}

/* ---- the variable table ---- */

static const FmuVariable *variable(unsigned int vr) {
    if (vr >= MODEL_VARIABLE_COUNT || !MODEL_VARIABLE_TABLE[vr].name) return NULL;
    return &MODEL_VARIABLE_TABLE[vr];
}

static bool settable(const Harness *h, const FmuVariable *v) {
    if (v->causality == FMU_INPUT) return IN(h->state, SETS);
    if (v->causality != FMU_PARAMETER) return false;
    if (v->variability == FMU_TUNABLE) return IN(h->state, SETS);
    return h->state == S_INSTANTIATED || h->state == S_INIT;
}

static bool in_range(const FmuVariable *v, double x) { return isfinite(x) && x >= v->min && x <= v->max; }

/* ---- logging ---- */

#if FMI_VERSION == 2
static void logger(fmi2ComponentEnvironment env, fmi2String name, fmi2Status status, fmi2String category,
                   fmi2String message, ...) {
    Harness *h = env;
    char text[4096];
    va_list args;
    REQUIRE(name && category && message, "logger called with a NULL string");
    /* importers treat the message as a printf format: every '%' must come escaped */
    va_start(args, message);
    vsnprintf(text, sizeof text, message, args);
    va_end(args);
    if (h->trace) fprintf(stderr, "    log %d %s: %s\n", status, category, text);
    if (status >= fmi2Error) h->errors_logged++;
}
#else
static void logger(fmi3InstanceEnvironment env, fmi3Status status, fmi3String category, fmi3String message) {
    Harness *h = env;
    REQUIRE(category && message && strlen(message) < 100000, "logger called with a NULL string");
    if (h->trace) fprintf(stderr, "    log %d %s: %s\n", status, category, message);
    if (status >= fmi3Error) h->errors_logged++;
}
#endif

/* ---- checks of one call's status ---- */

static void begin(Harness *h) { h->errors_logged = 0; }

/* `allowed`: the state machine allows the call now; `valid`: its arguments are valid (the FMU must not
 * reject it for them). Returns true when the call succeeded (OK or Warning). */
static bool outcome(Harness *h, const char *call, int status, bool allowed, bool valid) {
    if (h->trace)
        fprintf(stderr, "%-34s -> %d  (state %s, t = %.17g, allowed %d, valid %d)\n", call, status,
                STATE_NAMES[h->state], h->time, allowed, valid);
    REQUIRE(status >= STATUS_OK && status <= STATUS_ERROR && status != STATUS_DISCARD,
            "%s returned status %d in state %s", call, status, STATE_NAMES[h->state]);
    if (status == STATUS_ERROR) {
        REQUIRE(h->errors_logged > 0, "%s returned Error without logging an error message", call);
        h->state = S_ERROR;
        return false;
    }
    REQUIRE(allowed, "%s accepted (status %d) in state %s", call, status, STATE_NAMES[h->state]);
    REQUIRE(valid, "%s accepted invalid arguments (status %d)", call, status);
    return true;
}

static void expect_success(Harness *h, const char *call, int status) {
    REQUIRE(status == STATUS_OK, "%s: a valid call in state %s returned %d", call, STATE_NAMES[h->state], status);
}

/* ---- version-specific wrappers ---- */

#if FMI_VERSION == 2
#define C h->c
static int get_real(Harness *h, const unsigned *vr, size_t n, double *out, size_t n_out) {
    (void)n_out;
    return fmi2GetReal(C, vr, n, out);
}
static int set_real(Harness *h, const unsigned *vr, size_t n, const double *x, size_t n_x) {
    (void)n_x;
    return fmi2SetReal(C, vr, n, x);
}
static int get_int(Harness *h, const unsigned *vr, size_t n, int32_t *out) { return fmi2GetInteger(C, vr, n, out); }
static int set_int(Harness *h, const unsigned *vr, size_t n, const int32_t *x) { return fmi2SetInteger(C, vr, n, x); }
static int get_bool(Harness *h, const unsigned *vr, size_t n, bool *out) {
    fmi2Boolean b[MAX_VR];
    size_t i;
    int status = fmi2GetBoolean(C, vr, n, n ? b : NULL);
    for (i = 0; i < n && status == fmi2OK; i++) {
        REQUIRE(b[i] == fmi2True || b[i] == fmi2False, "fmi2GetBoolean returned %d", b[i]);
        out[i] = b[i] == fmi2True;
    }
    return status;
}
static int set_bool(Harness *h, const unsigned *vr, size_t n, const bool *x, uint8_t raw) {
    fmi2Boolean b[MAX_VR];
    size_t i;
    for (i = 0; i < n; i++) b[i] = x[i] ? (raw & 1 ? (fmi2Boolean)(raw | 1) : fmi2True) : fmi2False;
    return fmi2SetBoolean(C, vr, n, n ? b : NULL);
}
static int get_string(Harness *h, const unsigned *vr, size_t n, const char **out) { return fmi2GetString(C, vr, n, out); }
static int set_string(Harness *h, const unsigned *vr, size_t n, const char *const *x) { return fmi2SetString(C, vr, n, x); }
static int get_state(Harness *h, void **s) { return fmi2GetFMUstate(C, s); }
static int set_state(Harness *h, void *s) { return fmi2SetFMUstate(C, s); }
static int free_state(Harness *h, void **s) { return fmi2FreeFMUstate(C, s); }
static int state_size(Harness *h, void *s, size_t *n) { return fmi2SerializedFMUstateSize(C, s, n); }
static int serialize(Harness *h, void *s, unsigned char *b, size_t n) { return fmi2SerializeFMUstate(C, s, (fmi2Byte *)b, n); }
static int deserialize(Harness *h, const unsigned char *b, size_t n, void **s) {
    return fmi2DeSerializeFMUstate(C, (const fmi2Byte *)b, n, s);
}
static int do_step(Harness *h, double t, double dt) { return fmi2DoStep(C, t, dt, fmi2False); }
static int reset(Harness *h) { return fmi2Reset(C); }
static int terminate(Harness *h) { return fmi2Terminate(C); }
static int exit_init(Harness *h) { return fmi2ExitInitializationMode(C); }
static int debug_logging(Harness *h, bool on, size_t n, const char *const *categories) {
    return fmi2SetDebugLogging(C, on ? fmi2True : fmi2False, n, (fmi2String *)categories);
}
static int unsupported(Harness *h, uint8_t which) {
    fmi2Real x = 0.0;
    fmi2Integer order = 1;
    unsigned vr = 0;
    switch (which % 3) { /* fmi2GetStatus is op_status's: a status not provided is Discard, not Error */
    case 0: return fmi2GetDirectionalDerivative(C, &vr, 1, &vr, 1, &x, &x);
    case 1: return fmi2SetRealInputDerivatives(C, &vr, 1, &order, &x);
    default: return fmi2EnterEventMode(C);
    }
}
static void *instantiate(Harness *h, const char *name, const char *token, const char *resources, uint8_t variant) {
    return fmi2Instantiate(name, variant == 1 ? fmi2ModelExchange : fmi2CoSimulation, token, resources,
                           &h->callbacks, fmi2False, variant & 2 ? fmi2True : fmi2False);
}
static void free_instance(Harness *h) { fmi2FreeInstance(C); }
#undef C
#else
#define C h->c
static int get_real(Harness *h, const unsigned *vr, size_t n, double *out, size_t n_out) {
    return fmi3GetFloat64(C, vr, n, out, n_out);
}
static int set_real(Harness *h, const unsigned *vr, size_t n, const double *x, size_t n_x) {
    return fmi3SetFloat64(C, vr, n, x, n_x);
}
static int get_int(Harness *h, const unsigned *vr, size_t n, int32_t *out) { return fmi3GetInt32(C, vr, n, out, n); }
static int set_int(Harness *h, const unsigned *vr, size_t n, const int32_t *x) { return fmi3SetInt32(C, vr, n, x, n); }
static int get_bool(Harness *h, const unsigned *vr, size_t n, bool *out) { return fmi3GetBoolean(C, vr, n, out, n); }
static int set_bool(Harness *h, const unsigned *vr, size_t n, const bool *x, uint8_t raw) {
    (void)raw;
    return fmi3SetBoolean(C, vr, n, x, n);
}
static int get_string(Harness *h, const unsigned *vr, size_t n, const char **out) { return fmi3GetString(C, vr, n, out, n); }
static int set_string(Harness *h, const unsigned *vr, size_t n, const char *const *x) {
    return fmi3SetString(C, vr, n, x, n);
}
static int get_state(Harness *h, void **s) { return fmi3GetFMUState(C, s); }
static int set_state(Harness *h, void *s) { return fmi3SetFMUState(C, s); }
static int free_state(Harness *h, void **s) { return fmi3FreeFMUState(C, s); }
static int state_size(Harness *h, void *s, size_t *n) { return fmi3SerializedFMUStateSize(C, s, n); }
static int serialize(Harness *h, void *s, unsigned char *b, size_t n) { return fmi3SerializeFMUState(C, s, b, n); }
static int deserialize(Harness *h, const unsigned char *b, size_t n, void **s) {
    return fmi3DeserializeFMUState(C, b, n, s);
}
static int do_step(Harness *h, double t, double dt) {
    fmi3Boolean event = true, terminate_ = true, early = true;
    fmi3Float64 last = NAN;
    int status = fmi3DoStep(C, t, dt, fmi3False, &event, &terminate_, &early, &last);
    if (status <= fmi3Warning) {
        REQUIRE(!event && !terminate_ && !early, "fmi3DoStep: event/terminate/earlyReturn set");
        REQUIRE(last == t + dt, "fmi3DoStep: lastSuccessfulTime %.17g, expected %.17g", last, t + dt);
    }
    return status;
}
static int reset(Harness *h) { return fmi3Reset(C); }
static int terminate(Harness *h) { return fmi3Terminate(C); }
static int exit_init(Harness *h) { return fmi3ExitInitializationMode(C); }
static int debug_logging(Harness *h, bool on, size_t n, const char *const *categories) {
    return fmi3SetDebugLogging(C, on, n, (fmi3String *)categories);
}
static int unsupported(Harness *h, uint8_t which) {
    fmi3Float64 x = 0.0;
    unsigned vr = 0;
    size_t n = 0;
    switch (which % 4) {
    case 0: return fmi3GetDirectionalDerivative(C, &vr, 1, &vr, 1, &x, 1, &x, 1);
    case 1: return fmi3EnterEventMode(C);
    case 2: return fmi3GetNumberOfContinuousStates(C, &n);
    default: return fmi3EnterConfigurationMode(C);
    }
}
static void *instantiate(Harness *h, const char *name, const char *token, const char *resources, uint8_t variant) {
    return fmi3InstantiateCoSimulation(name, token, resources, false, (variant & 2) != 0, variant == 1, false, NULL,
                                       0, h, logger, NULL);
}
static void free_instance(Harness *h) { fmi3FreeInstance(C); }
#undef C
#endif

/* ---- helpers over whole states ---- */

/* Every Float64 value (arrays in full) into h->scratch; returns the status. */
static int get_all(Harness *h) {
    unsigned vr[256];
    size_t n = 0, i;
    for (i = 0; i < MODEL_VARIABLE_COUNT && n < 256; i++)
        if (variable((unsigned)i) && MODEL_VARIABLE_TABLE[i].type == FMU_FLOAT64) vr[n++] = (unsigned)i;
    return get_real(h, vr, n, h->scratch, h->n_values);
}

static void check_finite(Harness *h, const char *after) {
    size_t i;
    begin(h);
    expect_success(h, "GetFloat64 of every variable", get_all(h));
    for (i = 0; i < h->n_values; i++)
        REQUIRE(isfinite(h->scratch[i]), "after %s Float64 value %zu is %g (t = %g)", after, i, h->scratch[i], h->time);
    REQUIRE(h->scratch[0] == h->time || MODEL_VARIABLE_TABLE[0].type != FMU_FLOAT64, "time is %.17g, expected %.17g",
            h->scratch[0], h->time);
}

static void free_slot(Harness *h, Slot *s) {
    if (s->state) {
        begin(h);
        REQUIRE(free_state(h, &s->state) <= STATUS_WARNING || h->state == S_NONE, "FreeFMUState failed");
        REQUIRE(s->state == NULL, "FreeFMUState left the pointer set");
    }
    s->state = NULL;
    s->have_values = false;
}

static void free_all(Harness *h) {
    int k;
    for (k = 0; k < SLOTS; k++) free_slot(h, &h->slots[k]);
    if (h->c) free_instance(h);
    h->c = NULL;
    h->state = S_NONE;
}

/* ---- the calls ---- */

static char *fuzz_string(Harness *h, size_t *length) {
    size_t n = u8(h), i;
    char *s;
    if (n == 255) n = FMU_STRING_CAPACITY - 1 + (u8(h) % 3); /* at, and just past, the capacity */
    s = malloc(n + 1);
    REQUIRE(s != NULL, "out of memory");
    for (i = 0; i < n; i++) {
        char c = (char)(i < 200 ? u8(h) : 'x');
        s[i] = c ? c : '?';
    }
    s[n] = '\0';
    *length = n;
    return s;
}

static void op_instantiate(Harness *h) {
    uint8_t variant = u8(h) % 4, which = u8(h) % 12;
    char resources[4200];
    char *fuzzed = NULL;
    const char *location = resources, *token = INSTANTIATION_TOKEN, *name = h->name;
    size_t length;
    bool rejected, must_work;
    free_all(h);
    if (FUZZ_RESOURCES[0] == '\0')
        resources[0] = '\0';
    else if (FMI_VERSION == 2)
        snprintf(resources, sizeof resources, "file://%s/", FUZZ_RESOURCES);
    else
        snprintf(resources, sizeof resources, "%s", FUZZ_RESOURCES);
    switch (which) {
    case 0: location = NULL; break; /* no location: the built-in copies of the resources */
    case 1: location = ""; break;
    case 2: fuzzed = fuzz_string(h, &length), location = fuzzed; break;
    case 3: location = FMI_VERSION == 2 ? "file:///nonexistent/resources/" : "/nonexistent/resources"; break;
    case 4: fuzzed = fuzz_string(h, &length), token = fuzzed; break;
    case 5: token = NULL; break;
    case 6: name = NULL; break;
    case 7: name = ""; break;
    default: break; /* the FMU's own resources */
    }
    /* variant 1: model exchange (FMI 2) / event mode (FMI 3), not offered; 2: logging on */
    rejected = variant == 1 || !token || strcmp(token, INSTANTIATION_TOKEN) != 0 || !name || !name[0];
    /* a fuzzed or missing resource folder may or may not hold what the model reads (at instantiation or
     * later): only the FMU's own folder, none at all, or a model without resources must instantiate */
    must_work = !rejected && (which == 0 || which == 1 || which >= 8 || FUZZ_RESOURCES[0] == '\0');
    h->c = instantiate(h, name, token, location, variant);
    if (rejected) REQUIRE(h->c == NULL, "a bad instantiation was accepted (variant %u, case %u)", variant, which);
    if (must_work) REQUIRE(h->c != NULL, "instantiation failed (variant %u, case %u)", variant, which);
    free(fuzzed);
    if (h->c) {
        h->state = S_INSTANTIATED;
        h->time = 0.0;
        h->stop_defined = false;
        h->stop = 0.0;
        memset(&h->shadow, 0, sizeof h->shadow);
#if FMI_VERSION == 2
        h->setup_start = 0.0, h->setup_stop = 0.0, h->setup_stop_defined = false;
#endif
    }
}

static void op_enter_init(Harness *h) {
    double start = pick_value(h, 0.0, 10.0), stop = start + pick_value(h, -1.0, 100.0);
    bool stop_defined = u8(h) & 1, valid, allowed = h->state == S_INSTANTIATED;
    uint8_t setup = u8(h); /* read in both versions: the same input means the same calls in FMI 2 and 3 */
    int status;
#if FMI_VERSION == 2
    if (setup & 1) { /* with a fresh fmi2SetupExperiment */
        begin(h);
        status = fmi2SetupExperiment(h->c, fmi2False, 0.0, start, stop_defined, stop);
        valid = isfinite(start) && (!stop_defined || (isfinite(stop) && stop >= start));
        if (outcome(h, "fmi2SetupExperiment", status, allowed, valid)) {
            h->setup_start = start, h->setup_stop = stop, h->setup_stop_defined = stop_defined;
            h->time = start; /* the instance's time is the start time from now on */
        }
        allowed = h->state == S_INSTANTIATED;
    }
    start = h->setup_start, stop = h->setup_stop, stop_defined = h->setup_stop_defined;
    begin(h);
    status = fmi2EnterInitializationMode(h->c);
#else
    (void)setup;
    begin(h);
    status = fmi3EnterInitializationMode(h->c, false, 0.0, start, stop_defined, stop);
#endif
    valid = isfinite(start) && (!stop_defined || (isfinite(stop) && stop >= start));
    if (outcome(h, "EnterInitializationMode", status, allowed, valid)) {
        h->state = S_INIT;
        h->time = start;
        h->stop_defined = stop_defined;
        h->stop = stop;
    } else if (allowed && valid) {
        REQUIRE(0, "EnterInitializationMode rejected a valid experiment");
    }
}

static void op_exit_init(Harness *h) {
    bool allowed = h->state == S_INIT;
    begin(h);
    if (outcome(h, "ExitInitializationMode", exit_init(h), allowed, true)) {
        h->state = S_STEP;
        check_finite(h, "ExitInitializationMode");
    }
}

static void op_set_real(Harness *h) {
    unsigned vr[MAX_VR];
    double x[MAX_VR * MAX_ELEMENTS]; /* room for every element of MAX_VR arrays: nValues never overstates it */
    size_t n = u8(h) % (MAX_VR + 1), i, k, n_values = 0;
    bool valid = true, allowed = IN(h->state, SETS), null_arrays = false;
    uint8_t mode = u8(h);
    for (i = 0; i < n; i++) {
        const FmuVariable *v;
        size_t count;
        vr[i] = pick_vr(h);
        v = variable(vr[i]);
        count = v && v->type == FMU_FLOAT64 && v->count <= MAX_ELEMENTS ? v->count : 1;
        if (!v || v->type != FMU_FLOAT64 || v->count > MAX_ELEMENTS || !settable(h, v)) valid = false;
        for (k = 0; k < count; k++) { /* an FMI 3 array: all of its elements, each one checked by the FMU */
            x[n_values + k] = pick_value(h, v ? v->min : -1.0, v ? v->max : 1.0);
            if (v && !in_range(v, x[n_values + k])) valid = false;
        }
        n_values += count;
    }
    if (mode == 1 && n > 0) null_arrays = true, valid = false;
#if FMI_VERSION == 3
    if (mode == 2) n_values++, valid = false;
#endif
    begin(h);
    if (outcome(h, "SetFloat64", set_real(h, null_arrays ? NULL : vr, n, null_arrays ? NULL : x, n_values), allowed,
                valid)) {
        size_t next = 0;
        for (i = 0; i < n; i++) { /* scalars are compared when read back (valid: vr < 256) */
            const FmuVariable *v = variable(vr[i]);
            h->shadow.known[vr[i]] = v->count == 1;
            h->shadow.value[vr[i]] = x[next];
            next += v->count;
        }
    } else {
        REQUIRE(!(allowed && valid), "SetFloat64 rejected valid values");
        /* a rejected call may have set the values before the bad one (FMI leaves them undefined) */
        for (i = 0; i < n; i++)
            if (vr[i] < 256) h->shadow.known[vr[i]] = false;
    }
}

static void op_get_real(Harness *h) {
    unsigned vr[MAX_VR];
    double x[MAX_VR * 8];
    size_t n = u8(h) % (MAX_VR + 1), i, n_values = 0, next = 0;
    bool valid = true, allowed = IN(h->state, GETS);
    for (i = 0; i < n; i++) {
        const FmuVariable *v;
        vr[i] = pick_vr(h);
        v = variable(vr[i]);
        if (!v || v->type != FMU_FLOAT64 || v->count > 8) valid = false;
        n_values += v && v->type == FMU_FLOAT64 && v->count <= 8 ? v->count : 1;
    }
    begin(h);
    if (!outcome(h, "GetFloat64", get_real(h, vr, n, x, n_values), allowed, valid)) {
        REQUIRE(!(allowed && valid), "GetFloat64 failed on valid value references");
        return;
    }
    for (i = 0; i < n; i++) {
        const FmuVariable *v = variable(vr[i]);
        if (vr[i] == 0) REQUIRE(x[next] == h->time, "time is %.17g, expected %.17g", x[next], h->time);
        if (h->shadow.known[vr[i]] && v->count == 1)
            REQUIRE(memcmp(&x[next], &h->shadow.value[vr[i]], sizeof(double)) == 0,
                    "'%s' reads %.17g after being set to %.17g", v->name, x[next], h->shadow.value[vr[i]]);
        next += v->count;
    }
}

static void op_int_bool(Harness *h, bool integer, bool set) {
    unsigned vr[MAX_VR];
    int32_t xi[MAX_VR];
    bool xb[MAX_VR];
    size_t n = u8(h) % (MAX_VR + 1), i;
    uint8_t raw = u8(h);
    bool valid = true, allowed = IN(h->state, set ? SETS : GETS);
    int status;
    FmuType type = integer ? FMU_INT32 : FMU_BOOLEAN;
    for (i = 0; i < n; i++) {
        const FmuVariable *v;
        vr[i] = pick_vr(h);
        v = variable(vr[i]);
        if (integer) {
            uint8_t k = u8(h);
            xi[i] = k < 40 ? (int32_t)u32(h) : k < 60 ? INT32_MIN : k < 80 ? INT32_MAX : (int32_t)(k % 16) - 2;
            if (v && set && (xi[i] < v->min || xi[i] > v->max)) valid = false;
        } else {
            xb[i] = u8(h) & 1;
        }
        if (!v || v->type != type || (set && !settable(h, v))) valid = false;
    }
    begin(h);
    if (integer)
        status = set ? set_int(h, vr, n, xi) : get_int(h, vr, n, xi);
    else
        status = set ? set_bool(h, vr, n, xb, raw) : get_bool(h, vr, n, xb);
    if (!outcome(h, integer ? (set ? "SetInt32" : "GetInt32") : (set ? "SetBoolean" : "GetBoolean"), status, allowed,
                 valid))
        REQUIRE(!(allowed && valid), "a valid %s %s failed", integer ? "Int32" : "Boolean", set ? "set" : "get");
}

/* The file temp_program writes, one per process (in $TMPDIR, else /tmp), removed when the process exits so that
 * runs of the harness do not leave one file each behind. */
static char temp_program_path[4096];

static void remove_temp_program(void) {
    if (temp_program_path[0]) remove(temp_program_path);
}

static char *temp_program(Harness *h) {
    /* a file holding fuzzed text, for string parameters that name a file (the Interpolator's program) */
    char *path = temp_program_path;
    size_t length, n;
    char *text = fuzz_string(h, &length);
    FILE *f;
    if (!path[0]) {
        const char *folder = getenv("TMPDIR");
        if (!folder || !folder[0]) folder = "/tmp";
        snprintf(path, sizeof temp_program_path, "%s/fuzz_fmi_%ld.nc", folder, (long)getpid());
        REQUIRE(atexit(remove_temp_program) == 0, "cannot register the removal of %s", path);
    }
    f = fopen(path, "wb");
    REQUIRE(f != NULL, "cannot write %s", path);
    n = fwrite(text, 1, length, f);
    REQUIRE(n == length && fclose(f) == 0, "cannot write %s", path);
    free(text);
    return path;
}

/* A fuzzed string made a path no file can be read from or created at, whatever follows (a String parameter may
 * name a file read -- the Interpolator's program -- or written at Terminate -- the Workpiece's zmap_file, also
 * as "<path>.tmp"): it starts with "/dev/null/", and a path through a file that is no directory fails (ENOTDIR),
 * also for a process running as root and with ".." after it. A string at least as long as the prefix keeps its
 * length (the capacity's edge cases), a shorter one is appended to the prefix. */
static char *off_the_file_system(char *fuzzed, size_t *length) {
    static const char prefix[] = "/dev/null/";
    const size_t n = sizeof prefix - 1;
    char *path;
    if (*length >= n) {
        memcpy(fuzzed, prefix, n);
        return fuzzed;
    }
    path = malloc(n + *length + 1);
    REQUIRE(path != NULL, "out of memory");
    memcpy(path, prefix, n);
    memcpy(path + n, fuzzed, *length + 1);
    free(fuzzed);
    *length += n;
    return path;
}

static void op_string(Harness *h, bool set) {
    unsigned vr[2];
    const char *x[2];
    char *owned[2] = {NULL, NULL};
    size_t n = u8(h) % 3, i, length;
    bool valid = true, allowed = IN(h->state, set ? SETS : GETS);
    for (i = 0; i < n; i++) {
        const FmuVariable *v;
        uint8_t k = u8(h);
        vr[i] = pick_vr(h);
        v = variable(vr[i]);
        x[i] = NULL;
        if (set) {
            switch (k % 6) {
            case 0: x[i] = NULL, valid = false; break;
            case 1: x[i] = ""; break;
            case 2: x[i] = "/nonexistent/program.nc"; break;
            case 3: x[i] = "/proc/"; break; /* a directory, in which nothing can be created (a file written to it) */
            case 4: x[i] = temp_program(h); break;
            default:
                owned[i] = fuzz_string(h, &length);
                if (length > 0) owned[i] = off_the_file_system(owned[i], &length);
                x[i] = owned[i];
                if (length >= FMU_STRING_CAPACITY) valid = false;
                break;
            }
        }
        if (!v || v->type != FMU_STRING || (set && !settable(h, v))) valid = false;
    }
    begin(h);
    if (!outcome(h, set ? "SetString" : "GetString", set ? set_string(h, vr, n, x) : get_string(h, vr, n, x), allowed,
                 valid)) {
        REQUIRE(!(allowed && valid), "a valid string %s failed", set ? "set" : "get");
    } else if (!set) {
        for (i = 0; i < n; i++) REQUIRE(x[i] && strlen(x[i]) < FMU_STRING_CAPACITY, "GetString gave a bad string");
    }
    free(owned[0]);
    free(owned[1]);
}

static double pick_step(Harness *h) {
    uint8_t k = u8(h);
    switch (k % 16) {
    case 0: return 0.0;
    case 1: return -1e-3;
    case 2: return NAN;
    case 3: return INFINITY;
    case 4: return 1e300;
    case 5: return 4.9e-324;
    case 6: return 10.0;
    case 7: return raw64(h);
    default: return pow(10.0, -2.0 - (k % 5)); /* 1e-2 .. 1e-6 s */
    }
}

static bool step_once(Harness *h, double t, double dt) {
    double tolerance = fmin(1e-9 * fmax(1.0, fabs(h->time)), 0.25 * fabs(dt));
    bool allowed = h->state == S_STEP;
    bool valid = isfinite(dt) && dt > 0.0 && isfinite(t) && fabs(t - h->time) <= tolerance &&
                 isfinite(t + dt) && t + dt > t && !(h->stop_defined && t + dt > h->stop + tolerance);
    int status;
    begin(h);
    status = do_step(h, t, dt);
    if (!outcome(h, "DoStep", status, allowed, valid)) return false;
    h->time = t + dt;
    return true;
}

static void op_do_step(Harness *h) {
    uint8_t how = u8(h);
    double dt = pick_step(h), t = h->time;
    if (how % 8 == 0) t = pick_value(h, -1.0, 1.0);
    if (how % 8 == 1) t = h->time + 1e-3;
    if (how % 8 == 2) t = nextafter(h->time, INFINITY);
    if (step_once(h, t, dt)) check_finite(h, "DoStep");
}

static void op_run(Harness *h) {
    /* several valid steps at once: reach deep states cheaply */
    int n = 1 + u8(h) % 64, k;
    double dt = pow(10.0, -3.0 - u8(h) % 3);
    for (k = 0; k < n && h->state == S_STEP; k++) {
        if (h->stop_defined && h->time + dt > h->stop) break;
        if (!step_once(h, h->time, dt)) return;
    }
    if (h->state == S_STEP) check_finite(h, "DoStep");
}

static void remember(const Harness *h, Slot *s) {
    s->harness_state = h->state;
    s->time = h->time;
    s->stop = h->stop;
    s->stop_defined = h->stop_defined;
#if FMI_VERSION == 2
    s->setup_start = h->setup_start, s->setup_stop = h->setup_stop, s->setup_stop_defined = h->setup_stop_defined;
#endif
    s->shadow = h->shadow;
}

static void op_get_state(Harness *h) {
    Slot *s = &h->slots[u8(h) % SLOTS];
    bool allowed = IN(h->state, ANY);
    begin(h);
    if (!outcome(h, "GetFMUState", get_state(h, &s->state), allowed, true)) {
        REQUIRE(!allowed, "GetFMUState failed");
        return;
    }
    remember(h, s);
    s->have_values = IN(h->state, GETS);
    if (s->have_values) {
        begin(h);
        expect_success(h, "GetFloat64 of every variable", get_all(h));
        memcpy(s->values, h->scratch, h->n_values * sizeof(double));
    }
}

static void restored(Harness *h, const Slot *s, const char *how) {
    h->state = s->harness_state;
    h->time = s->time;
    h->stop = s->stop;
    h->stop_defined = s->stop_defined;
#if FMI_VERSION == 2
    h->setup_start = s->setup_start, h->setup_stop = s->setup_stop, h->setup_stop_defined = s->setup_stop_defined;
#endif
    h->shadow = s->shadow;
    if (s->have_values) {
        size_t i;
        begin(h);
        expect_success(h, "GetFloat64 of every variable", get_all(h));
        for (i = 0; i < h->n_values; i++)
            REQUIRE(memcmp(&h->scratch[i], &s->values[i], sizeof(double)) == 0,
                    "%s: Float64 value %zu is %.17g, it was %.17g when the state was taken", how, i, h->scratch[i],
                    s->values[i]);
    }
}

static void op_set_state(Harness *h) {
    Slot *s = &h->slots[u8(h) % SLOTS];
    bool allowed = IN(h->state, ANY) && s->state != NULL;
    begin(h);
    if (outcome(h, "SetFMUState", set_state(h, s->state), allowed, true))
        restored(h, s, "SetFMUState");
    else
        REQUIRE(!allowed, "SetFMUState of a state of this instance failed");
}

static void op_free_state(Harness *h) {
    Slot *s = &h->slots[u8(h) % SLOTS];
    if (h->state == S_NONE) return;
    begin(h);
    if (outcome(h, "FreeFMUState", free_state(h, &s->state), true, true)) {
        REQUIRE(s->state == NULL, "FreeFMUState left the pointer set");
        s->have_values = false;
    }
}

/* Serialize the state of one slot, then deserialize it (intact, with one bit flipped, or truncated) into
 * another: an intact copy restores what the original does, a damaged one is rejected. */
static void op_serialize(Harness *h) {
    Slot *from = &h->slots[u8(h) % SLOTS], *to = &h->slots[u8(h) % SLOTS];
    uint8_t damage = u8(h);
    uint32_t where = u32(h);
    size_t size = 0;
    unsigned char *bytes;
    void *fresh = NULL;
    bool allowed = from->state != NULL, intact;
    int status;
    begin(h);
    status = state_size(h, from->state, &size);
    if (!outcome(h, "SerializedFMUStateSize", status, allowed, true)) {
        REQUIRE(!allowed, "SerializedFMUStateSize failed");
        return;
    }
    REQUIRE(size > 0 && size < (1u << 30), "serialized state of %zu bytes", size); /* Workpiece: up to 160 MB */
    bytes = malloc(size);
    REQUIRE(bytes != NULL, "out of memory");
    begin(h);
    if (damage == 1) { /* a buffer one byte too small */
        outcome(h, "SerializeFMUState (small buffer)", serialize(h, from->state, bytes, size - 1), true, false);
        free(bytes);
        return;
    }
    status = serialize(h, from->state, bytes, size);
    expect_success(h, "SerializeFMUState", status);
    intact = !(damage >= 2 && damage < 72);
    if (damage >= 2 && damage < 64) /* one bit flipped */
        bytes[where % size] ^= (unsigned char)(1u << (damage % 8));
    else if (damage >= 64 && damage < 72) /* truncated */
        size = where % size;
    begin(h);
    status = deserialize(h, bytes, size, &fresh);
    free(bytes);
    if (!outcome(h, intact ? "DeserializeFMUState" : "DeserializeFMUState (damaged bytes)", status, true, intact)) {
        REQUIRE(!intact, "DeserializeFMUState rejected an intact state");
        REQUIRE(fresh == NULL, "a rejected DeserializeFMUState returned a state");
        return;
    }
    REQUIRE(fresh != NULL, "DeserializeFMUState returned no state");
    if (to != from) {
        double *values = to->values;
        free_slot(h, to);
        *to = *from;
        to->values = values;
        memcpy(to->values, from->values, h->n_values * sizeof(double));
    } else {
        begin(h);
        expect_success(h, "FreeFMUState", free_state(h, &from->state));
    }
    to->state = fresh;
}

static void op_reset(Harness *h) {
    bool allowed = IN(h->state, ANY);
    int status;
    begin(h);
    status = reset(h);
    if (outcome(h, "Reset", status, allowed, true)) {
        h->state = S_INSTANTIATED;
        h->time = 0.0;
        h->stop_defined = false;
        memset(&h->shadow, 0, sizeof h->shadow);
#if FMI_VERSION == 2
        h->setup_start = 0.0, h->setup_stop = 0.0, h->setup_stop_defined = false;
#endif
    } else {
        REQUIRE(!allowed, "Reset failed");
    }
}

static void op_terminate(Harness *h) {
    bool allowed = h->state == S_STEP;
    begin(h);
    if (outcome(h, "Terminate", terminate(h), allowed, true)) h->state = S_TERMINATED;
}

static void op_debug_logging(Harness *h) {
    static const char *const known[] = {"logEvents", "logStatusWarning", "logStatusError", "logAll", NULL};
    const char *categories[3];
    size_t n = u8(h) % 4, i;
    bool valid = true, on = u8(h) & 1;
    for (i = 0; i < n && i < 3; i++) {
        categories[i] = known[u8(h) % 5];
        if (!categories[i]) valid = false;
    }
    begin(h);
    outcome(h, "SetDebugLogging", debug_logging(h, on, n, categories), IN(h->state, ANY), valid);
}

static void op_unsupported(Harness *h) {
    uint8_t which = u8(h);
    begin(h);
    outcome(h, "an unsupported function", unsupported(h, which), IN(h->state, ANY), false);
}

#if FMI_VERSION == 2
static void op_status(Harness *h) {
    fmi2Real t = NAN;
    fmi2Status status;
    int discarded;
    bool allowed = IN(h->state, GETS);
    begin(h);
    if (outcome(h, "fmi2GetRealStatus", fmi2GetRealStatus(h->c, fmi2LastSuccessfulTime, &t), allowed, true))
        REQUIRE(t == h->time, "fmi2LastSuccessfulTime %.17g, expected %.17g", t, h->time);
    else
        REQUIRE(!allowed, "fmi2GetRealStatus failed");
    if (!IN(h->state, GETS)) return;
    /* a status the FMU does not provide: Discard, and the state is unchanged (FMI 2.0, 4.2.3) */
    begin(h);
    discarded = fmi2GetStatus(h->c, fmi2DoStepStatus, &status);
    REQUIRE(discarded == fmi2Discard && h->errors_logged == 0, "fmi2GetStatus returned %d in state %s", discarded,
            STATE_NAMES[h->state]);
}
#endif

static void op_null_instance(Harness *h) {
    /* no instance: Error, and nothing else happens */
#if FMI_VERSION == 2
    REQUIRE(fmi2DoStep(NULL, 0.0, 1e-3, fmi2False) == fmi2Error && fmi2Reset(NULL) == fmi2Error,
            "a NULL instance was accepted");
    fmi2FreeInstance(NULL);
#else
    REQUIRE(fmi3Reset(NULL) == fmi3Error && fmi3ExitInitializationMode(NULL) == fmi3Error,
            "a NULL instance was accepted");
    fmi3FreeInstance(NULL);
#endif
    (void)h;
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size) {
    Harness h;
    size_t i, calls = 0;
    int k;
    REQUIRE(MODEL_VARIABLE_COUNT <= 256, "the shadow holds 256 value references, the table has %u", MODEL_VARIABLE_COUNT);
    memset(&h, 0, sizeof h);
    h.data = data, h.size = size;
    h.trace = getenv("FUZZ_FMI_TRACE") != NULL;
    snprintf(h.name, sizeof h.name, "fuzz");
#if FMI_VERSION == 2
    h.callbacks.logger = logger;
    h.callbacks.allocateMemory = calloc;
    h.callbacks.freeMemory = free;
    h.callbacks.componentEnvironment = &h;
#endif
    for (i = 0; i < MODEL_VARIABLE_COUNT; i++)
        if (variable((unsigned)i) && MODEL_VARIABLE_TABLE[i].type == FMU_FLOAT64) h.n_values += MODEL_VARIABLE_TABLE[i].count;
    h.scratch = malloc(h.n_values * sizeof(double));
    REQUIRE(h.scratch != NULL, "out of memory");
    for (k = 0; k < SLOTS; k++) {
        h.slots[k].values = malloc(h.n_values * sizeof(double));
        REQUIRE(h.slots[k].values != NULL, "out of memory");
    }
    /* every program starts with an instance (its first byte picks the instantiation) */
    op_instantiate(&h);
    while (more(&h) && calls++ < 200) {
        uint8_t op = u8(&h);
        if (op % 24 == 0) {
            op_instantiate(&h);
            continue;
        }
        if (op % 24 == 23) {
            op_null_instance(&h);
            continue;
        }
        if (h.state == S_NONE) continue;
        switch (op % 24) {
        case 1: op_enter_init(&h); break;
        case 2: op_exit_init(&h); break;
        case 3: op_set_real(&h); break;
        case 4: op_get_real(&h); break;
        case 5: op_int_bool(&h, true, true); break;
        case 6: op_int_bool(&h, true, false); break;
        case 7: op_int_bool(&h, false, true); break;
        case 8: op_int_bool(&h, false, false); break;
        case 9: op_string(&h, true); break;
        case 10: op_string(&h, false); break;
        case 11: op_do_step(&h); break;
        case 12: op_run(&h); break;
        case 13: op_get_state(&h); break;
        case 14: op_set_state(&h); break;
        case 15: op_free_state(&h); break;
        case 16: op_serialize(&h); break;
        case 17: op_reset(&h); break;
        case 18: op_terminate(&h); break;
        case 19: op_debug_logging(&h); break;
        case 20: op_unsupported(&h); break;
#if FMI_VERSION == 2
        case 21: op_status(&h); break;
#endif
        case 22: free_all(&h); break;
        default: op_run(&h); break;
        }
    }
    free_all(&h);
    for (k = 0; k < SLOTS; k++) free(h.slots[k].values);
    free(h.scratch);
    return 0;
}
