/* A minimal co-simulation importer for checking a cross-built FMU binary on its own platform (the Windows DLL
 * under wine in tests/test_cross_platform.py): loads the library, instantiates, sets inputs, steps, prints outputs.
 *
 *   fmu_driver LIBRARY FMI_VERSION TOKEN RESOURCES STEP_SIZE STEPS [VR=A[:B] ...] -- [VR ...]
 *
 * LIBRARY: the binary (.dll/.so/.dylib); FMI_VERSION: 2 or 3; TOKEN: the guid (FMI 2) or instantiationToken
 * (FMI 3); RESOURCES: the resource location (FMI 2: a file URI; FMI 3: a path ending in a separator);
 * VR=A:B sets the Real/Float64 input VR to A + B*t before each step (B defaults to 0); the value references after
 * "--" are the Real/Float64 scalars printed after each step: one line "t v1 v2 ..." with %.17g (exact round trip).
 * Exit status 0 when every call returned OK or Warning; otherwise 1, with the failing call on stderr. */
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2FunctionTypes.h"
#include "fmi3FunctionTypes.h"

#if defined(_WIN32)
#include <windows.h>
typedef HMODULE Library;
static Library open_library(const char *path) { return LoadLibraryA(path); }
static void *symbol(Library lib, const char *name) { return (void *)(size_t)GetProcAddress(lib, name); }
#else
#include <dlfcn.h>
typedef void *Library;
static Library open_library(const char *path) { return dlopen(path, RTLD_NOW | RTLD_LOCAL); }
static void *symbol(Library lib, const char *name) { return dlsym(lib, name); }
#endif

#define MAX_VARIABLES 256

typedef struct {
    unsigned vr;
    double a, b; /* value a + b*t */
} Input;

typedef struct {
    Input inputs[MAX_VARIABLES];
    size_t n_inputs;
    unsigned outputs[MAX_VARIABLES];
    size_t n_outputs;
    double step;
    long steps;
} Run;

static void fmi2_logger(fmi2ComponentEnvironment env, fmi2String name, fmi2Status status, fmi2String category,
                        fmi2String message, ...) {
    (void)env;
    if (status == fmi2OK) return;
    fprintf(stderr, "[%s %d %s] %s\n", name ? name : "", (int)status, category ? category : "", message);
}

static void fmi3_logger(fmi3InstanceEnvironment env, fmi3Status status, fmi3String category, fmi3String message) {
    (void)env;
    if (status == fmi3OK) return;
    fprintf(stderr, "[%d %s] %s\n", (int)status, category ? category : "", message);
}

static void *must(Library lib, const char *name) {
    void *f = symbol(lib, name);
    if (!f) {
        fprintf(stderr, "the library exports no %s\n", name);
        exit(1);
    }
    return f;
}

static int check(int status, const char *call) {
    if (status > 1) fprintf(stderr, "%s returned status %d\n", call, status);
    return status > 1;
}

static void print_line(double t, const double *values, size_t n) {
    size_t i;
    printf("%.17g", t);
    for (i = 0; i < n; i++) printf(" %.17g", values[i]);
    printf("\n");
}

static int set_inputs_fmi2(fmi2SetRealTYPE *set_real, fmi2Component c, const Run *run, double t) {
    size_t i;
    int failed = 0;
    for (i = 0; i < run->n_inputs; i++) {
        const fmi2ValueReference vr = run->inputs[i].vr;
        const double value = run->inputs[i].a + run->inputs[i].b * t;
        failed |= check(set_real(c, &vr, 1, &value), "fmi2SetReal");
    }
    return failed;
}

static int set_inputs_fmi3(fmi3SetFloat64TYPE *set_float, fmi3Instance c, const Run *run, double t) {
    size_t i;
    int failed = 0;
    for (i = 0; i < run->n_inputs; i++) {
        const fmi3ValueReference vr = run->inputs[i].vr;
        const double value = run->inputs[i].a + run->inputs[i].b * t;
        failed |= check(set_float(c, &vr, 1, &value, 1), "fmi3SetFloat64");
    }
    return failed;
}

static int run_fmi2(Library lib, const char *token, const char *resources, const Run *run) {
    fmi2CallbackFunctions callbacks = {fmi2_logger, calloc, free, NULL, NULL};
    fmi2InstantiateTYPE *instantiate = (fmi2InstantiateTYPE *)must(lib, "fmi2Instantiate");
    fmi2SetupExperimentTYPE *setup = (fmi2SetupExperimentTYPE *)must(lib, "fmi2SetupExperiment");
    fmi2EnterInitializationModeTYPE *enter =
        (fmi2EnterInitializationModeTYPE *)must(lib, "fmi2EnterInitializationMode");
    fmi2ExitInitializationModeTYPE *exit_init =
        (fmi2ExitInitializationModeTYPE *)must(lib, "fmi2ExitInitializationMode");
    fmi2SetRealTYPE *set_real = (fmi2SetRealTYPE *)must(lib, "fmi2SetReal");
    fmi2GetRealTYPE *get_real = (fmi2GetRealTYPE *)must(lib, "fmi2GetReal");
    fmi2DoStepTYPE *do_step = (fmi2DoStepTYPE *)must(lib, "fmi2DoStep");
    fmi2TerminateTYPE *terminate = (fmi2TerminateTYPE *)must(lib, "fmi2Terminate");
    fmi2FreeInstanceTYPE *free_instance = (fmi2FreeInstanceTYPE *)must(lib, "fmi2FreeInstance");
    double values[MAX_VARIABLES];
    double t = 0.0;
    long k;
    int failed = 0;
    fmi2Component c = instantiate("driver", fmi2CoSimulation, token, resources, &callbacks, fmi2False, fmi2False);
    if (!c) {
        fprintf(stderr, "fmi2Instantiate returned NULL\n");
        return 1;
    }
    failed |= check(setup(c, fmi2False, 0.0, 0.0, fmi2False, 0.0), "fmi2SetupExperiment");
    failed |= check(enter(c), "fmi2EnterInitializationMode");
    failed |= set_inputs_fmi2(set_real, c, run, 0.0); /* the inputs at t = 0 are known at initialization */
    failed |= check(exit_init(c), "fmi2ExitInitializationMode");
    for (k = 0; k < run->steps && !failed; k++) {
        failed |= set_inputs_fmi2(set_real, c, run, t);
        failed |= check(do_step(c, t, run->step, fmi2True), "fmi2DoStep");
        t = (double)(k + 1) * run->step;
        failed |= check(get_real(c, run->outputs, run->n_outputs, values), "fmi2GetReal");
        if (!failed) print_line(t, values, run->n_outputs);
    }
    failed |= check(terminate(c), "fmi2Terminate");
    free_instance(c);
    return failed;
}

static int run_fmi3(Library lib, const char *token, const char *resources, const Run *run) {
    fmi3InstantiateCoSimulationTYPE *instantiate =
        (fmi3InstantiateCoSimulationTYPE *)must(lib, "fmi3InstantiateCoSimulation");
    fmi3EnterInitializationModeTYPE *enter =
        (fmi3EnterInitializationModeTYPE *)must(lib, "fmi3EnterInitializationMode");
    fmi3ExitInitializationModeTYPE *exit_init =
        (fmi3ExitInitializationModeTYPE *)must(lib, "fmi3ExitInitializationMode");
    fmi3SetFloat64TYPE *set_float = (fmi3SetFloat64TYPE *)must(lib, "fmi3SetFloat64");
    fmi3GetFloat64TYPE *get_float = (fmi3GetFloat64TYPE *)must(lib, "fmi3GetFloat64");
    fmi3DoStepTYPE *do_step = (fmi3DoStepTYPE *)must(lib, "fmi3DoStep");
    fmi3TerminateTYPE *terminate = (fmi3TerminateTYPE *)must(lib, "fmi3Terminate");
    fmi3FreeInstanceTYPE *free_instance = (fmi3FreeInstanceTYPE *)must(lib, "fmi3FreeInstance");
    double values[MAX_VARIABLES];
    double t = 0.0;
    long k;
    int failed = 0;
    fmi3Boolean event = fmi3False, stop = fmi3False, early = fmi3False;
    fmi3Float64 last = 0.0;
    fmi3Instance c = instantiate("driver", token, resources, fmi3False, fmi3False, fmi3False, fmi3False, NULL, 0,
                                 NULL, fmi3_logger, NULL);
    if (!c) {
        fprintf(stderr, "fmi3InstantiateCoSimulation returned NULL\n");
        return 1;
    }
    failed |= check(enter(c, fmi3False, 0.0, 0.0, fmi3False, 0.0), "fmi3EnterInitializationMode");
    failed |= set_inputs_fmi3(set_float, c, run, 0.0);
    failed |= check(exit_init(c), "fmi3ExitInitializationMode");
    for (k = 0; k < run->steps && !failed; k++) {
        failed |= set_inputs_fmi3(set_float, c, run, t);
        failed |= check(do_step(c, t, run->step, fmi3True, &event, &stop, &early, &last), "fmi3DoStep");
        t = (double)(k + 1) * run->step;
        failed |= check(get_float(c, run->outputs, run->n_outputs, values, run->n_outputs), "fmi3GetFloat64");
        if (!failed) print_line(t, values, run->n_outputs);
    }
    failed |= check(terminate(c), "fmi3Terminate");
    free_instance(c);
    return failed;
}

static int parse_args(int argc, char **argv, Run *run) {
    int i = 7, outputs = 0;
    char *end;
    run->step = strtod(argv[5], &end);
    if (*end || !(run->step > 0.0)) return fprintf(stderr, "STEP_SIZE '%s' is not a positive number\n", argv[5]), 1;
    run->steps = strtol(argv[6], &end, 10);
    if (*end || run->steps < 1) return fprintf(stderr, "STEPS '%s' is not a positive integer\n", argv[6]), 1;
    for (; i < argc; i++) {
        if (strcmp(argv[i], "--") == 0) {
            outputs = 1;
        } else if (outputs) {
            if (run->n_outputs == MAX_VARIABLES) return fprintf(stderr, "more than %d outputs\n", MAX_VARIABLES), 1;
            run->outputs[run->n_outputs] = (unsigned)strtoul(argv[i], &end, 10);
            if (*end) return fprintf(stderr, "output '%s' is not a value reference\n", argv[i]), 1;
            run->n_outputs++;
        } else {
            Input *in = &run->inputs[run->n_inputs];
            if (run->n_inputs == MAX_VARIABLES) return fprintf(stderr, "more than %d inputs\n", MAX_VARIABLES), 1;
            in->vr = (unsigned)strtoul(argv[i], &end, 10);
            if (*end != '=') return fprintf(stderr, "input '%s' is not VR=A[:B]\n", argv[i]), 1;
            in->a = strtod(end + 1, &end);
            in->b = 0.0;
            if (*end == ':') in->b = strtod(end + 1, &end);
            if (*end) return fprintf(stderr, "input '%s' is not VR=A[:B]\n", argv[i]), 1;
            run->n_inputs++;
        }
    }
    return 0;
}

int main(int argc, char **argv) {
    static Run run;
    Library lib;
    if (argc < 7) {
        fprintf(stderr, "usage: %s LIBRARY FMI_VERSION TOKEN RESOURCES STEP_SIZE STEPS [VR=A[:B] ...] -- [VR ...]\n",
                argv[0]);
        return 2;
    }
    if (parse_args(argc, argv, &run)) return 2;
    lib = open_library(argv[1]);
    if (!lib) {
        fprintf(stderr, "cannot load the library '%s'\n", argv[1]);
        return 1;
    }
    if (strcmp(argv[2], "2") == 0) return run_fmi2(lib, argv[3], argv[4], &run);
    if (strcmp(argv[2], "3") == 0) return run_fmi3(lib, argv[3], argv[4], &run);
    fprintf(stderr, "FMI_VERSION '%s' is not 2 or 3\n", argv[2]);
    return 2;
}
