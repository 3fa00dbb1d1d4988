/* Lifecycle test of one built FMU binary, run by ctest under valgrind memcheck:
 * 2,000 instantiate / initialize / step / FMU-state / reset / free cycles plus illegal calls,
 * through the real shared library (dlopen), for FMI 2 or FMI 3 (FMI_VERSION). Compiled per FMU
 * against its generated variable table, so it sets every input and reads every output.
 * Usage: lifecycle_test <FMU shared library> [<resource location>]: even cycles pass the location (FMI 2:
 * a file URI, FMI 3: a path), so FMUs with resources read and parse them 1,000 times; odd cycles pass ""
 * (the FMUs' built-in copies). */
#include <dlfcn.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "model_generated.h"

#if FMI_VERSION == 2
#include "fmi2Functions.h"
#else
#include "fmi3Functions.h"
#endif

#define CYCLES 2000
#define STEPS 10

static int failures = 0;
static const char *resources = "";
static int errors_logged = 0;

#define CHECK(condition, ...)                                                                                  \
    do {                                                                                                       \
        if (!(condition)) {                                                                                    \
            failures++;                                                                                        \
            fprintf(stderr, "FAILED line %d: ", __LINE__);                                                     \
            fprintf(stderr, __VA_ARGS__);                                                                      \
            fprintf(stderr, "\n");                                                                             \
        }                                                                                                      \
    } while (0)

static void *load(void *library, const char *name) {
    void *symbol = dlsym(library, name);
    if (!symbol) {
        fprintf(stderr, "missing symbol %s\n", name);
        exit(2);
    }
    return symbol;
}

#define LOAD(name) name##TYPE *name = (name##TYPE *)load(library, #name)

static unsigned int first_vr(FmuCausality causality, FmuType type) {
    unsigned int i;
    for (i = 0; i < MODEL_VARIABLE_COUNT; i++)
        if (MODEL_VARIABLE_TABLE[i].name && MODEL_VARIABLE_TABLE[i].causality == causality &&
            MODEL_VARIABLE_TABLE[i].type == type && MODEL_VARIABLE_TABLE[i].count == 1)
            return i;
    return 0;
}

#if FMI_VERSION == 2
static void logger(fmi2ComponentEnvironment env, fmi2String name, fmi2Status status, fmi2String category,
                   fmi2String message, ...) {
    (void)env, (void)name, (void)category, (void)message;
    if (status >= fmi2Error) errors_logged++;
}

static int run(void *library) {
    fmi2CallbackFunctions callbacks = {logger, calloc, free, NULL, NULL};
    LOAD(fmi2Instantiate);
    LOAD(fmi2FreeInstance);
    LOAD(fmi2SetupExperiment);
    LOAD(fmi2EnterInitializationMode);
    LOAD(fmi2ExitInitializationMode);
    LOAD(fmi2DoStep);
    LOAD(fmi2GetReal);
    LOAD(fmi2SetReal);
    LOAD(fmi2Reset);
    LOAD(fmi2Terminate);
    LOAD(fmi2GetFMUstate);
    LOAD(fmi2SetFMUstate);
    LOAD(fmi2FreeFMUstate);
    LOAD(fmi2SerializedFMUstateSize);
    LOAD(fmi2SerializeFMUstate);
    LOAD(fmi2DeSerializeFMUstate);
    unsigned int out = first_vr(FMU_OUTPUT, FMU_FLOAT64), in = first_vr(FMU_INPUT, FMU_FLOAT64);
    int cycle, k;
    double nan_value = NAN;

    CHECK(fmi2Instantiate("x", fmi2CoSimulation, "{wrong}", "", &callbacks, fmi2False, fmi2False) == NULL,
          "wrong GUID must be rejected");
    for (cycle = 0; cycle < CYCLES; cycle++) {
        fmi2Component c = fmi2Instantiate("lifecycle", fmi2CoSimulation, INSTANTIATION_TOKEN,
                                          cycle % 2 ? "" : resources, &callbacks, fmi2False, fmi2False);
        fmi2FMUstate state = NULL, restored = NULL;
        double before, after, t = 0.0, h = 1e-3;
        size_t size = 0;
        fmi2Byte *bytes;
        CHECK(c != NULL, "instantiate");
        if (!c) return 1;
        CHECK(fmi2DoStep(c, 0.0, h, fmi2True) == fmi2Error, "doStep before initialization must fail");
        CHECK(fmi2Reset(c) == fmi2OK, "reset after error");
        CHECK(fmi2SetupExperiment(c, fmi2False, 0.0, 0.0, fmi2False, 0.0) == fmi2OK, "setup");
        CHECK(fmi2EnterInitializationMode(c) == fmi2OK, "enter init");
        CHECK(fmi2ExitInitializationMode(c) == fmi2OK, "exit init");
        for (k = 0; k < STEPS; k++, t += h) CHECK(fmi2DoStep(c, t, h, fmi2True) == fmi2OK, "step");
        CHECK(fmi2GetFMUstate(c, &state) == fmi2OK, "get state");
        CHECK(fmi2GetReal(c, &out, 1, &before) == fmi2OK, "get");
        CHECK(fmi2DoStep(c, t, h, fmi2True) == fmi2OK, "step");
        CHECK(fmi2SetFMUstate(c, state) == fmi2OK, "set state");
        CHECK(fmi2GetReal(c, &out, 1, &after) == fmi2OK && before == after, "rollback");
        CHECK(fmi2SerializedFMUstateSize(c, state, &size) == fmi2OK, "state size");
        bytes = malloc(size);
        CHECK(fmi2SerializeFMUstate(c, state, bytes, size) == fmi2OK, "serialize");
        CHECK(fmi2DeSerializeFMUstate(c, bytes, size, &restored) == fmi2OK, "deserialize");
        CHECK(fmi2DeSerializeFMUstate(c, bytes, size - 1, &restored) == fmi2Error, "truncated state");
        free(bytes);
        CHECK(fmi2Reset(c) == fmi2OK, "reset");
        CHECK(fmi2FreeFMUstate(c, &state) == fmi2OK && state == NULL, "free state");
        CHECK(fmi2FreeFMUstate(c, &restored) == fmi2OK, "free restored");
        CHECK(fmi2SetupExperiment(c, fmi2False, 0.0, 0.0, fmi2True, 1.0) == fmi2OK, "setup after reset");
        CHECK(fmi2EnterInitializationMode(c) == fmi2OK, "enter init");
        CHECK(fmi2SetReal(c, &in, 1, &nan_value) == fmi2Error, "NaN input must fail");
        CHECK(fmi2Terminate(c) == fmi2Error, "terminate in error state must fail");
        fmi2FreeInstance(c);
    }
    return 0;
}
#else
static void logger(fmi3InstanceEnvironment env, fmi3Status status, fmi3String category, fmi3String message) {
    (void)env, (void)category, (void)message;
    if (status >= fmi3Error) errors_logged++;
}

static int run(void *library) {
    LOAD(fmi3InstantiateCoSimulation);
    LOAD(fmi3FreeInstance);
    LOAD(fmi3EnterInitializationMode);
    LOAD(fmi3ExitInitializationMode);
    LOAD(fmi3DoStep);
    LOAD(fmi3GetFloat64);
    LOAD(fmi3SetFloat64);
    LOAD(fmi3Reset);
    LOAD(fmi3Terminate);
    LOAD(fmi3GetFMUState);
    LOAD(fmi3SetFMUState);
    LOAD(fmi3FreeFMUState);
    LOAD(fmi3SerializedFMUStateSize);
    LOAD(fmi3SerializeFMUState);
    LOAD(fmi3DeserializeFMUState);
    unsigned int out = first_vr(FMU_OUTPUT, FMU_FLOAT64), in = first_vr(FMU_INPUT, FMU_FLOAT64);
    int cycle, k;
    double nan_value = NAN;
    fmi3Boolean event, terminate, early;
    double last;

    CHECK(fmi3InstantiateCoSimulation("x", "{wrong}", "", false, false, false, false, NULL, 0, NULL, logger, NULL) ==
              NULL,
          "wrong token must be rejected");
    for (cycle = 0; cycle < CYCLES; cycle++) {
        fmi3Instance c = fmi3InstantiateCoSimulation("lifecycle", INSTANTIATION_TOKEN, cycle % 2 ? "" : resources,
                                                     false, false, false, false, NULL, 0, NULL, logger, NULL);
        fmi3FMUState state = NULL, restored = NULL;
        double before, after, t = 0.0, h = 1e-3;
        size_t size = 0;
        fmi3Byte *bytes;
        CHECK(c != NULL, "instantiate");
        if (!c) return 1;
        CHECK(fmi3DoStep(c, 0.0, h, true, &event, &terminate, &early, &last) == fmi3Error,
              "doStep before initialization must fail");
        CHECK(fmi3Reset(c) == fmi3OK, "reset after error");
        CHECK(fmi3EnterInitializationMode(c, false, 0.0, 0.0, false, 0.0) == fmi3OK, "enter init");
        CHECK(fmi3ExitInitializationMode(c) == fmi3OK, "exit init");
        for (k = 0; k < STEPS; k++, t += h)
            CHECK(fmi3DoStep(c, t, h, true, &event, &terminate, &early, &last) == fmi3OK, "step");
        CHECK(fmi3GetFMUState(c, &state) == fmi3OK, "get state");
        CHECK(fmi3GetFloat64(c, &out, 1, &before, 1) == fmi3OK, "get");
        CHECK(fmi3GetFloat64(c, &out, 1, &before, 2) == fmi3Error, "nValues mismatch must fail");
        CHECK(fmi3Reset(c) == fmi3OK, "reset");
        CHECK(fmi3SetFMUState(c, state) == fmi3OK, "set state");
        CHECK(fmi3GetFloat64(c, &out, 1, &after, 1) == fmi3OK && before == after, "rollback");
        CHECK(fmi3SerializedFMUStateSize(c, state, &size) == fmi3OK, "state size");
        bytes = malloc(size);
        CHECK(fmi3SerializeFMUState(c, state, bytes, size) == fmi3OK, "serialize");
        CHECK(fmi3DeserializeFMUState(c, bytes, size, &restored) == fmi3OK, "deserialize");
        bytes[0] ^= 0xff;
        CHECK(fmi3DeserializeFMUState(c, bytes, size, &restored) == fmi3Error, "corrupt state must fail");
        free(bytes);
        CHECK(fmi3Reset(c) == fmi3OK, "reset");
        CHECK(fmi3FreeFMUState(c, &state) == fmi3OK && state == NULL, "free state");
        CHECK(fmi3FreeFMUState(c, &restored) == fmi3OK, "free restored");
        CHECK(fmi3EnterInitializationMode(c, false, 0.0, 0.0, true, 1.0) == fmi3OK, "enter init after reset");
        CHECK(fmi3SetFloat64(c, &in, 1, &nan_value, 1) == fmi3Error, "NaN input must fail");
        CHECK(fmi3Terminate(c) == fmi3Error, "terminate in error state must fail");
        fmi3FreeInstance(c);
    }
    return 0;
}
#endif

int main(int argc, char **argv) {
    void *library;
    int status;
    if (argc != 2 && argc != 3) {
        fprintf(stderr, "usage: %s <FMU shared library> [<resource location>]\n", argv[0]);
        return 2;
    }
    if (argc == 3) resources = argv[2];
    library = dlopen(argv[1], RTLD_NOW | RTLD_LOCAL);
    if (!library) {
        fprintf(stderr, "cannot load %s: %s\n", argv[1], dlerror());
        return 2;
    }
    status = run(library);
    dlclose(library);
    CHECK(errors_logged > 0, "errors must be logged");
    printf("%s FMI %d: %d cycles (resources '%s'), %d errors logged as expected, %d failures\n",
           MODEL_IDENTIFIER_STRING, FMI_VERSION, CYCLES, resources, errors_logged, failures);
    return status != 0 || failures != 0;
}
