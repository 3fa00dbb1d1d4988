/* A plain C co-simulation driver: the native limit of the stepping benchmark
 * (tests/benchmarks/stepping_bench.py writes its configuration and runs it).
 *
 *     build/stepper/stepping_driver CONFIG
 *
 * It dlopens the FMUs' binaries (already extracted), instantiates them, sets parameters and
 * constant inputs, initializes and steps them on the fixed grid with the semantics of
 * orchestrator/master.py (Gauss-Seidel in execution order, multi-rate, recorded inputs sampled
 * as numpy's interp / searchsorted do, connections with and without delay, unit factors), reads
 * the recorded outputs once per output interval into memory and writes them at the end as raw
 * float64 rows (time first) to the output file, with the guarantee the orchestrator gives its final
 * run.json: through a temporary file and a rename (complete or absent), fsynced with its folder
 * (durable). It is written independently of the orchestrator's stepping library (fmus/stepper/),
 * but for the sampling arithmetic numpy dictates (recorded_sample.h), so that it measures what a
 * hand-written C master costs, and does the same FMI calls the orchestrator does, so both do the
 * same work; the benchmark checks that their results are bit-identical.
 *
 * CONFIG: one directive per line, fields separated by spaces (instances are numbered from 0 in
 * the order of their "instance" lines, which is the execution order):
 *     grid START BASE N_TICKS TICKS_PER_OUTPUT
 *     recorded FILE N_SAMPLES N_CHANNELS     float64 rows: time, then each channel (SI)
 *     instance NAME FMI_VERSION TICKS_PER_STEP LIBRARY TOKEN RESOURCE_LOCATION
 *     start INSTANCE real|int|bool|string VR VALUE   parameter or constant input, before initialization
 *                                                      (a string: the rest of the line)
 *     input INSTANCE real|bool VR CHANNEL linear|hold FACTOR
 *     link INSTANCE real|bool VR SOURCE_INSTANCE SOURCE_VR DELAY(0|1) FACTOR
 *     record INSTANCE real|bool|int VR
 *     output FILE
 * Prints "wall_s=... loop_s=... rows=..." (CLOCK_MONOTONIC): wall_s from the start of main() to
 * the end (configuration read, FMU binaries dlopened, instantiated, initialized, stepped, the rows
 * written to FILE atomically and durably, instances freed, libraries closed); loop_s the stepping alone.
 * No global state; exits 1 with a message on any FMI error.
 */
#define _POSIX_C_SOURCE 200809L

#include <dlfcn.h>
#include <fcntl.h>
#include <stdarg.h>
#include <stdbool.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include "fmi2FunctionTypes.h"
#include "fmi3FunctionTypes.h"
#include "recorded_sample.h"

#define MAX_FIELDS 16

typedef struct {
    int channel, linear;
    double factor;
} RecIn;

typedef struct {
    int source, source_slot, delay, is_bool;
    double factor;
} Link;

typedef struct {
    char name[128];
    int fmi, m;
    void *library, *component;
    /* FMI 2 */
    fmi2SetRealTYPE *set_real2;
    fmi2SetIntegerTYPE *set_integer2;
    fmi2SetBooleanTYPE *set_boolean2;
    fmi2SetStringTYPE *set_string2;
    fmi2GetIntegerTYPE *get_integer2;
    fmi2GetRealTYPE *get_real2;
    fmi2GetBooleanTYPE *get_boolean2;
    fmi2DoStepTYPE *do_step2;
    fmi2SetupExperimentTYPE *setup_experiment2;
    fmi2EnterInitializationModeTYPE *enter_init2;
    fmi2ExitInitializationModeTYPE *exit_init2;
    fmi2TerminateTYPE *terminate2;
    fmi2FreeInstanceTYPE *free2;
    fmi2CallbackFunctions callbacks;
    /* FMI 3 */
    fmi3SetFloat64TYPE *set_float64;
    fmi3SetInt32TYPE *set_int32;
    fmi3SetBooleanTYPE *set_boolean3;
    fmi3SetStringTYPE *set_string3;
    fmi3GetInt32TYPE *get_int32;
    fmi3GetFloat64TYPE *get_float64;
    fmi3GetBooleanTYPE *get_boolean3;
    fmi3DoStepTYPE *do_step3;
    fmi3EnterInitializationModeTYPE *enter_init3;
    fmi3ExitInitializationModeTYPE *exit_init3;
    fmi3TerminateTYPE *terminate3;
    fmi3FreeInstanceTYPE *free3;
    /* inputs: recorded first, then links, per type (as the orchestrator orders them) */
    int n_rin, n_bin, n_rrec, n_brec;
    unsigned int vr_rin[64], vr_bin[64];
    double rin[64];
    int bin2[64];
    bool bin3[64];
    RecIn rrec[64], brec[64];
    int n_rlinks, n_blinks;
    Link rlinks[64], blinks[64];
    /* outputs: what links read and what is recorded, per type (Int32: recorded only) */
    int n_rout, n_bout, n_iout;
    unsigned int vr_rout[256], vr_bout[64], vr_iout[64];
    int32_t iout[64];
    double rout[256], rprev[256];
    int bout2[64], bprev2[64];
    bool bout3[64], bprev3[64];
    int feeds, snapshot, has_outputs;
} Inst;

enum { KIND_REAL, KIND_BOOL, KIND_INT };

typedef struct {
    int inst, kind, slot;
} Column;

typedef struct {
    double start, base;
    long long n_ticks, tpo;
    int n_inst, n_cols, n_channels;
    long n_samples;
    Inst *inst;
    Column cols[256];
    double *table; /* n_samples x (1 + n_channels) */
    char output[4096];
} Sim;

static double now(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

static void die(const char *format, ...) {
    va_list args;
    va_start(args, format);
    fprintf(stderr, "stepping_driver: ");
    vfprintf(stderr, format, args);
    fprintf(stderr, "\n");
    va_end(args);
    exit(1);
}

static void *symbol(void *library, const char *name) {
    void *p = dlsym(library, name);
    if (p == NULL) {
        die("missing symbol %s", name);
    }
    return p;
}

/* function pointers from dlsym without an object-to-function pointer cast (ISO C) */
#define LOAD(lib, field, name)                        \
    do {                                              \
        void *p_ = symbol((lib), (name));             \
        memcpy(&(field), &p_, sizeof(field));         \
    } while (0)

static void check(int status, const Inst *s, const char *what, double t) {
    if (status > 1) {
        die("%s of instance '%s' at t = %.17g s returned status %d", what, s->name, t, status);
    }
}

static void logger2(fmi2ComponentEnvironment env, fmi2String name, fmi2Status status, fmi2String category,
                    fmi2String message, ...) {
    va_list args;
    (void)env, (void)category;
    va_start(args, message);
    if (status >= fmi2Warning) {
        fprintf(stderr, "%s: ", name ? name : "?");
        vfprintf(stderr, message, args);
        fprintf(stderr, "\n");
    }
    va_end(args);
}

static void logger3(fmi3InstanceEnvironment env, fmi3Status status, fmi3String category, fmi3String message) {
    (void)env, (void)category;
    if (status >= fmi3Warning) {
        fprintf(stderr, "%s\n", message);
    }
}

static void instantiate(Inst *s, const char *library, const char *token, const char *resource) {
    s->library = dlopen(library, RTLD_NOW | RTLD_LOCAL);
    if (s->library == NULL) {
        die("cannot load %s: %s", library, dlerror());
    }
    if (s->fmi == 2) {
        fmi2InstantiateTYPE *inst2;
        LOAD(s->library, inst2, "fmi2Instantiate");
        LOAD(s->library, s->set_real2, "fmi2SetReal");
        LOAD(s->library, s->set_integer2, "fmi2SetInteger");
        LOAD(s->library, s->set_boolean2, "fmi2SetBoolean");
        LOAD(s->library, s->set_string2, "fmi2SetString");
        LOAD(s->library, s->get_integer2, "fmi2GetInteger");
        LOAD(s->library, s->get_real2, "fmi2GetReal");
        LOAD(s->library, s->get_boolean2, "fmi2GetBoolean");
        LOAD(s->library, s->do_step2, "fmi2DoStep");
        LOAD(s->library, s->setup_experiment2, "fmi2SetupExperiment");
        LOAD(s->library, s->enter_init2, "fmi2EnterInitializationMode");
        LOAD(s->library, s->exit_init2, "fmi2ExitInitializationMode");
        LOAD(s->library, s->terminate2, "fmi2Terminate");
        LOAD(s->library, s->free2, "fmi2FreeInstance");
        s->callbacks.logger = logger2;
        s->callbacks.allocateMemory = calloc;
        s->callbacks.freeMemory = free;
        s->component = inst2(s->name, fmi2CoSimulation, token, resource, &s->callbacks, fmi2False, fmi2False);
    } else {
        fmi3InstantiateCoSimulationTYPE *inst3;
        LOAD(s->library, inst3, "fmi3InstantiateCoSimulation");
        LOAD(s->library, s->set_float64, "fmi3SetFloat64");
        LOAD(s->library, s->set_int32, "fmi3SetInt32");
        LOAD(s->library, s->set_boolean3, "fmi3SetBoolean");
        LOAD(s->library, s->set_string3, "fmi3SetString");
        LOAD(s->library, s->get_int32, "fmi3GetInt32");
        LOAD(s->library, s->get_float64, "fmi3GetFloat64");
        LOAD(s->library, s->get_boolean3, "fmi3GetBoolean");
        LOAD(s->library, s->do_step3, "fmi3DoStep");
        LOAD(s->library, s->enter_init3, "fmi3EnterInitializationMode");
        LOAD(s->library, s->exit_init3, "fmi3ExitInitializationMode");
        LOAD(s->library, s->terminate3, "fmi3Terminate");
        LOAD(s->library, s->free3, "fmi3FreeInstance");
        s->component = inst3(s->name, token, resource, false, false, false, false, NULL, 0, NULL, logger3, NULL);
    }
    if (s->component == NULL) {
        die("cannot instantiate %s from %s", s->name, library);
    }
}

static void set_start(Inst *s, const char *type, unsigned int vr, const char *text) {
    int status;
    if (strcmp(type, "real") == 0) {
        double v = strtod(text, NULL);
        status = s->fmi == 2 ? (int)s->set_real2(s->component, &vr, 1, &v)
                             : (int)s->set_float64(s->component, &vr, 1, &v, 1);
    } else if (strcmp(type, "int") == 0) {
        int v = (int)strtol(text, NULL, 10);
        int32_t v3 = (int32_t)v;
        status = s->fmi == 2 ? (int)s->set_integer2(s->component, &vr, 1, &v)
                             : (int)s->set_int32(s->component, &vr, 1, &v3, 1);
    } else if (strcmp(type, "string") == 0) {
        status = s->fmi == 2 ? (int)s->set_string2(s->component, &vr, 1, &text)
                             : (int)s->set_string3(s->component, &vr, 1, &text, 1);
    } else {
        int v = (int)strtol(text, NULL, 10);
        bool v3 = v != 0;
        status = s->fmi == 2 ? (int)s->set_boolean2(s->component, &vr, 1, &v)
                             : (int)s->set_boolean3(s->component, &vr, 1, &v3, 1);
    }
    check(status, s, "set start value", 0.0);
}

/* The output slot of vr in s (added if new). */
static int out_slot(Inst *s, int kind, unsigned int vr) {
    unsigned int *vrs = kind == KIND_BOOL ? s->vr_bout : kind == KIND_INT ? s->vr_iout : s->vr_rout;
    int *n = kind == KIND_BOOL ? &s->n_bout : kind == KIND_INT ? &s->n_iout : &s->n_rout;
    int i;
    for (i = 0; i < *n; ++i) {
        if (vrs[i] == vr) {
            return i;
        }
    }
    if (*n >= (kind == KIND_REAL ? 256 : 64)) {
        die("too many outputs in %s", s->name);
    }
    vrs[*n] = vr;
    return (*n)++;
}

/* Channel `channel` at t, as orchestrator.recorded samples it (numpy's interp / searchsorted): the
 * arithmetic numpy dictates is shared with the stepper (recorded_sample.h); the benchmark checks it
 * against the Python path, which calls numpy itself. */
static double sample(const Sim *sim, int channel, int linear, double t, int64_t *guess) {
    const int64_t w = 1 + sim->n_channels;
    return recorded_sample(sim->table, sim->table + 1 + channel, w, sim->n_samples, linear, t, guess);
}

static void feed(Sim *sim, Inst *s, double t, int64_t *guess) {
    int i;
    for (i = 0; i < s->n_rrec; ++i) {
        s->rin[i] = sample(sim, s->rrec[i].channel, s->rrec[i].linear, t, &guess[i]) * s->rrec[i].factor;
    }
    for (i = 0; i < s->n_brec; ++i) {
        double v = sample(sim, s->brec[i].channel, 0, t, &guess[32 + i]);
        s->bin2[i] = v != 0.0;
        s->bin3[i] = v != 0.0;
    }
    for (i = 0; i < s->n_rlinks; ++i) {
        const Link *l = &s->rlinks[i];
        const Inst *src = &sim->inst[l->source];
        s->rin[s->n_rrec + i] = (l->delay ? src->rprev : src->rout)[l->source_slot] * l->factor;
    }
    for (i = 0; i < s->n_blinks; ++i) {
        const Link *l = &s->blinks[i];
        const Inst *src = &sim->inst[l->source];
        int v = src->fmi == 2 ? (l->delay ? src->bprev2 : src->bout2)[l->source_slot]
                              : (int)(l->delay ? src->bprev3 : src->bout3)[l->source_slot];
        s->bin2[s->n_brec + i] = v;
        s->bin3[s->n_brec + i] = v != 0;
    }
    if (s->fmi == 2) {
        if (s->n_rin) check((int)s->set_real2(s->component, s->vr_rin, (size_t)s->n_rin, s->rin), s, "SetReal", t);
        if (s->n_bin) check((int)s->set_boolean2(s->component, s->vr_bin, (size_t)s->n_bin, s->bin2), s, "SetBoolean", t);
    } else {
        if (s->n_rin)
            check((int)s->set_float64(s->component, s->vr_rin, (size_t)s->n_rin, s->rin, (size_t)s->n_rin), s,
                  "SetFloat64", t);
        if (s->n_bin)
            check((int)s->set_boolean3(s->component, s->vr_bin, (size_t)s->n_bin, s->bin3, (size_t)s->n_bin), s,
                  "SetBoolean", t);
    }
}

static void get_outputs(Inst *s, double t) {
    if (s->fmi == 2) {
        if (s->n_rout) check((int)s->get_real2(s->component, s->vr_rout, (size_t)s->n_rout, s->rout), s, "GetReal", t);
        if (s->n_bout)
            check((int)s->get_boolean2(s->component, s->vr_bout, (size_t)s->n_bout, s->bout2), s, "GetBoolean", t);
        if (s->n_iout)
            check((int)s->get_integer2(s->component, s->vr_iout, (size_t)s->n_iout, s->iout), s, "GetInteger", t);
    } else {
        if (s->n_rout)
            check((int)s->get_float64(s->component, s->vr_rout, (size_t)s->n_rout, s->rout, (size_t)s->n_rout), s,
                  "GetFloat64", t);
        if (s->n_bout)
            check((int)s->get_boolean3(s->component, s->vr_bout, (size_t)s->n_bout, s->bout3, (size_t)s->n_bout), s,
                  "GetBoolean", t);
        if (s->n_iout)
            check((int)s->get_int32(s->component, s->vr_iout, (size_t)s->n_iout, s->iout, (size_t)s->n_iout), s,
                  "GetInt32", t);
    }
}

static void snapshot(Inst *s) {
    memcpy(s->rprev, s->rout, sizeof(double) * (size_t)s->n_rout);
    memcpy(s->bprev2, s->bout2, sizeof(int) * (size_t)s->n_bout);
    memcpy(s->bprev3, s->bout3, sizeof(bool) * (size_t)s->n_bout);
}

static void write_row(const Sim *sim, double *row, double t) {
    int c;
    row[0] = t;
    for (c = 0; c < sim->n_cols; ++c) {
        const Column *col = &sim->cols[c];
        const Inst *s = &sim->inst[col->inst];
        row[1 + c] = col->kind == KIND_REAL  ? s->rout[col->slot]
                     : col->kind == KIND_INT ? (double)s->iout[col->slot]
                     : s->fmi == 2           ? (double)s->bout2[col->slot]
                                             : (s->bout3[col->slot] ? 1.0 : 0.0);
    }
}

static int split(char *line, char **fields) {
    int n = 0;
    char *save = NULL, *tok = strtok_r(line, " \t\r\n", &save);
    while (tok != NULL && n < MAX_FIELDS) {
        fields[n++] = tok;
        tok = strtok_r(NULL, " \t\r\n", &save);
    }
    return n;
}

static void read_config(Sim *sim, const char *path) {
    char line[8192], raw[8192], *f[MAX_FIELDS];
    FILE *fh = fopen(path, "r");
    if (fh == NULL) {
        die("cannot open %s", path);
    }
    sim->inst = calloc(64, sizeof(Inst));
    if (sim->inst == NULL) {
        die("out of memory");
    }
    while (fgets(line, sizeof line, fh) != NULL) {
        int n;
        memcpy(raw, line, sizeof raw);
        n = split(line, f);
        if (n == 0) {
            continue;
        }
        if (strcmp(f[0], "grid") == 0 && n == 5) {
            sim->start = strtod(f[1], NULL);
            sim->base = strtod(f[2], NULL);
            sim->n_ticks = strtoll(f[3], NULL, 10);
            sim->tpo = strtoll(f[4], NULL, 10);
        } else if (strcmp(f[0], "recorded") == 0 && n == 4) {
            FILE *data = fopen(f[1], "rb");
            size_t count;
            sim->n_samples = strtol(f[2], NULL, 10);
            sim->n_channels = (int)strtol(f[3], NULL, 10);
            count = (size_t)sim->n_samples * (size_t)(1 + sim->n_channels);
            sim->table = malloc(count * sizeof(double));
            if (data == NULL || sim->table == NULL || fread(sim->table, sizeof(double), count, data) != count) {
                die("cannot read %s", f[1]);
            }
            fclose(data);
        } else if (strcmp(f[0], "instance") == 0 && n == 7) {
            Inst *s = &sim->inst[sim->n_inst++];
            snprintf(s->name, sizeof s->name, "%s", f[1]);
            s->fmi = (int)strtol(f[2], NULL, 10);
            s->m = (int)strtol(f[3], NULL, 10);
            instantiate(s, f[4], f[5], f[6]);
        } else if (strcmp(f[0], "start") == 0 && n >= 5 && strcmp(f[2], "string") == 0) {
            char *text = raw + (f[4] - line); /* the rest of the line, spaces included */
            text[strcspn(text, "\r\n")] = '\0';
            set_start(&sim->inst[strtol(f[1], NULL, 10)], f[2], (unsigned int)strtoul(f[3], NULL, 10), text);
        } else if (strcmp(f[0], "start") == 0 && n == 5) {
            set_start(&sim->inst[strtol(f[1], NULL, 10)], f[2], (unsigned int)strtoul(f[3], NULL, 10), f[4]);
        } else if (strcmp(f[0], "input") == 0 && n == 7) {
            Inst *s = &sim->inst[strtol(f[1], NULL, 10)];
            int is_bool = strcmp(f[2], "bool") == 0;
            RecIn *r = is_bool ? &s->brec[s->n_brec++] : &s->rrec[s->n_rrec++];
            (is_bool ? s->vr_bin : s->vr_rin)[is_bool ? s->n_bin++ : s->n_rin++] =
                (unsigned int)strtoul(f[3], NULL, 10);
            r->channel = (int)strtol(f[4], NULL, 10);
            r->linear = strcmp(f[5], "linear") == 0;
            r->factor = strtod(f[6], NULL);
        } else if (strcmp(f[0], "link") == 0 && n == 8) {
            Inst *s = &sim->inst[strtol(f[1], NULL, 10)];
            int is_bool = strcmp(f[2], "bool") == 0;
            Link *l = is_bool ? &s->blinks[s->n_blinks++] : &s->rlinks[s->n_rlinks++];
            Inst *src;
            (is_bool ? s->vr_bin : s->vr_rin)[is_bool ? s->n_bin++ : s->n_rin++] =
                (unsigned int)strtoul(f[3], NULL, 10);
            l->source = (int)strtol(f[4], NULL, 10);
            src = &sim->inst[l->source];
            l->source_slot = out_slot(src, is_bool ? KIND_BOOL : KIND_REAL, (unsigned int)strtoul(f[5], NULL, 10));
            l->delay = (int)strtol(f[6], NULL, 10);
            l->is_bool = is_bool;
            l->factor = strtod(f[7], NULL);
            src->feeds = 1;
            src->has_outputs = 1;
            if (l->delay) {
                src->snapshot = 1;
            }
        } else if (strcmp(f[0], "record") == 0 && n == 4) {
            Column *c = &sim->cols[sim->n_cols++];
            Inst *s;
            c->inst = (int)strtol(f[1], NULL, 10);
            c->kind = strcmp(f[2], "bool") == 0 ? KIND_BOOL : strcmp(f[2], "int") == 0 ? KIND_INT : KIND_REAL;
            s = &sim->inst[c->inst];
            c->slot = out_slot(s, c->kind, (unsigned int)strtoul(f[3], NULL, 10));
            s->has_outputs = 1;
        } else if (strcmp(f[0], "output") == 0 && n == 2) {
            snprintf(sim->output, sizeof sim->output, "%s", f[1]);
        } else {
            die("bad line in %s: %s ...", path, f[0]);
        }
    }
    fclose(fh);
}

/* As orchestrator/results.py writes the final run.json: a temporary file, fsync, rename, fsync of the folder. */
static void write_durably(const char *path, const double *rows, size_t row_size, size_t n_rows) {
    char tmp[4200], folder[4096];
    const char *slash = strrchr(path, '/');
    FILE *out;
    int fd;
    snprintf(tmp, sizeof tmp, "%s.tmp", path);
    snprintf(folder, sizeof folder, "%.*s", slash == NULL ? 1 : (int)(slash - path), slash == NULL ? "." : path);
    out = fopen(tmp, "wb");
    if (out == NULL || fwrite(rows, row_size, n_rows, out) != n_rows || fflush(out) != 0 || fsync(fileno(out)) != 0 ||
        fclose(out) != 0 || rename(tmp, path) != 0) {
        die("cannot write %s", path);
    }
    fd = open(folder, O_RDONLY);
    if (fd < 0 || fsync(fd) != 0 || close(fd) != 0) {
        die("cannot fsync the folder %s", folder);
    }
}

int main(int argc, char **argv) {
    const double t_begin = now();
    double t_loop, loop_s, *rows;
    Sim sim;
    int64_t guess[64][64];
    long long k, n_rows_max, n_rows = 0;
    int i;

    if (argc != 2) {
        fprintf(stderr, "usage: %s CONFIG\n", argv[0]);
        return 2;
    }
    memset(&sim, 0, sizeof sim);
    memset(guess, 0, sizeof guess);
    read_config(&sim, argv[1]);
    n_rows_max = sim.n_ticks / sim.tpo + 1;
    rows = malloc((size_t)n_rows_max * (size_t)(1 + sim.n_cols) * sizeof(double));
    if (rows == NULL) {
        die("out of memory for %lld rows", n_rows_max);
    }

    /* initialization, as the orchestrator's setup */
    for (i = 0; i < sim.n_inst; ++i) {
        Inst *s = &sim.inst[i];
        if (s->fmi == 2) {
            check((int)s->setup_experiment2(s->component, fmi2False, 0.0, sim.start, fmi2False, 0.0), s,
                  "SetupExperiment", sim.start);
            check((int)s->enter_init2(s->component), s, "EnterInitializationMode", sim.start);
        } else {
            check((int)s->enter_init3(s->component, false, 0.0, sim.start, false, 0.0), s,
                  "EnterInitializationMode", sim.start);
        }
    }
    for (i = 0; i < sim.n_inst; ++i) {
        feed(&sim, &sim.inst[i], sim.start, guess[i]);
        get_outputs(&sim.inst[i], sim.start);
    }
    for (i = 0; i < sim.n_inst; ++i) {
        Inst *s = &sim.inst[i];
        check(s->fmi == 2 ? (int)s->exit_init2(s->component) : (int)s->exit_init3(s->component), s,
              "ExitInitializationMode", sim.start);
        get_outputs(s, sim.start);
        snapshot(s);
    }
    write_row(&sim, rows, sim.start);
    n_rows = 1;

    /* the loop */
    t_loop = now();
    for (k = 0; k < sim.n_ticks; ++k) {
        const double t = sim.start + (double)k * sim.base;
        for (i = 0; i < sim.n_inst; ++i) {
            if (sim.inst[i].snapshot) {
                snapshot(&sim.inst[i]);
            }
        }
        for (i = 0; i < sim.n_inst; ++i) {
            Inst *s = &sim.inst[i];
            long long next;
            double h;
            if (k % s->m != 0) {
                continue;
            }
            feed(&sim, s, t, guess[i]);
            next = k + s->m < sim.n_ticks ? k + s->m : sim.n_ticks;
            h = (sim.start + (double)next * sim.base) - t;
            if (s->fmi == 2) {
                check((int)s->do_step2(s->component, t, h, fmi2True), s, "DoStep", t);
            } else {
                bool event = false, terminate = false, early = false;
                double last = 0.0;
                check((int)s->do_step3(s->component, t, h, true, &event, &terminate, &early, &last), s, "DoStep", t);
            }
            if (s->feeds) {
                get_outputs(s, t);
            }
        }
        if ((k + 1) % sim.tpo == 0) {
            const double t_row = sim.start + (double)(k + 1) * sim.base;
            for (i = 0; i < sim.n_inst; ++i) {
                if (sim.inst[i].has_outputs) {
                    get_outputs(&sim.inst[i], t_row);
                }
            }
            write_row(&sim, rows + n_rows * (1 + sim.n_cols), t_row);
            ++n_rows;
        }
    }
    loop_s = now() - t_loop;

    write_durably(sim.output, rows, sizeof(double) * (size_t)(1 + sim.n_cols), (size_t)n_rows);
    for (i = 0; i < sim.n_inst; ++i) {
        Inst *s = &sim.inst[i];
        if (s->fmi == 2) {
            s->terminate2(s->component);
            s->free2(s->component);
        } else {
            s->terminate3(s->component);
            s->free3(s->component);
        }
        dlclose(s->library);
    }
    free(rows);
    free(sim.table);
    free(sim.inst);
    printf("wall_s=%.6f loop_s=%.6f rows=%lld\n", now() - t_begin, loop_s, n_rows);
    return 0;
}
