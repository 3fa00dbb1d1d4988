/* FMI 2.0 co-simulation entry points, mapped onto the version-independent core (fmu_instance.c). */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"
#include "fmu_instance.h"

#define INSTANCE ((FmuInstance *)c)

/* Every entry point starts with this: a NULL instance cannot log, so it only returns Error. */
#define BEGIN(name, allowed)                                                                                  \
    static const char *const function = name;                                                                 \
    if (!c) return fmi2Error;                                                                                 \
    if (fmu_check_state(INSTANCE, function, (allowed)) != FMU_OK) return (fmi2Status)fmu_fail(INSTANCE, FMU_ERROR)

#define RETURN(status) return (fmi2Status)fmu_fail(INSTANCE, (status))

/* FMI 2 loggers take printf formats: '%' and '#' in our finished message are escaped. */
static void log_sink(const FmuInstance *instance, FmuStatus status, const char *category, const char *message) {
    char escaped[2048];
    size_t i, j = 0;
    fmi2CallbackLogger logger = (fmi2CallbackLogger)instance->importer_logger;
    for (i = 0; message[i] != '\0' && j + 2 < sizeof escaped; i++) {
        if (message[i] == '%' || message[i] == '#') escaped[j++] = message[i];
        escaped[j++] = message[i];
    }
    escaped[j] = '\0';
    logger(instance->importer_environment, instance->name, (fmi2Status)status, category, escaped);
}

const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }
const char *fmi2GetVersion(void) { return fmi2Version; }

fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                              fmi2String fmuResourceLocation, const fmi2CallbackFunctions *functions,
                              fmi2Boolean visible, fmi2Boolean loggingOn) {
    FmuCallback logger = functions ? (FmuCallback)functions->logger : NULL;
    void *environment = functions ? functions->componentEnvironment : NULL;
    (void)visible;
    if (fmuType != fmi2CoSimulation) {
        fmu_log_without_instance(log_sink, logger, environment, instanceName,
                                 "fmi2Instantiate: this FMU supports co-simulation only (fmuType = fmi2ModelExchange)");
        return NULL;
    }
    return fmu_create("fmi2Instantiate", instanceName, fmuGUID, fmuResourceLocation, log_sink, logger, environment,
                      loggingOn != fmi2False);
}

void fmi2FreeInstance(fmi2Component c) { fmu_destroy(INSTANCE); }

fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean loggingOn, size_t nCategories,
                               const fmi2String categories[]) {
    BEGIN("fmi2SetDebugLogging", STATES_ANY);
    RETURN(fmu_set_debug_logging(INSTANCE, loggingOn != fmi2False, nCategories, categories));
}

fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean toleranceDefined, fmi2Real tolerance,
                               fmi2Real startTime, fmi2Boolean stopTimeDefined, fmi2Real stopTime) {
    BEGIN("fmi2SetupExperiment", STATE_INSTANTIATED);
    (void)toleranceDefined;
    (void)tolerance;
    if (fmu_check_experiment(INSTANCE, function, startTime, stopTimeDefined != fmi2False, stopTime) != FMU_OK)
        RETURN(FMU_ERROR);
    INSTANCE->start_time = startTime;
    INSTANCE->time = startTime;
    INSTANCE->stop_time_defined = stopTimeDefined != fmi2False;
    INSTANCE->stop_time = stopTime;
    return fmi2OK;
}

fmi2Status fmi2EnterInitializationMode(fmi2Component c) {
    BEGIN("fmi2EnterInitializationMode", STATE_INSTANTIATED);
    RETURN(fmu_enter_initialization(INSTANCE, function, INSTANCE->start_time, INSTANCE->stop_time_defined,
                                    INSTANCE->stop_time));
}

fmi2Status fmi2ExitInitializationMode(fmi2Component c) {
    BEGIN("fmi2ExitInitializationMode", STATE_INITIALIZATION_MODE);
    RETURN(fmu_exit_initialization(INSTANCE, function));
}

fmi2Status fmi2Terminate(fmi2Component c) {
    BEGIN("fmi2Terminate", STATE_STEP_MODE);
    RETURN(fmu_terminate(INSTANCE, function));
}

fmi2Status fmi2Reset(fmi2Component c) {
    BEGIN("fmi2Reset", STATES_ANY);
    return (fmi2Status)fmu_reset(INSTANCE);
}

fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Real value[]) {
    BEGIN("fmi2GetReal", STATES_GET);
    RETURN(fmu_get_float64s(INSTANCE, function, vr, nvr, value, nvr));
}

fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Real value[]) {
    BEGIN("fmi2SetReal", STATES_SET);
    RETURN(fmu_set_float64s(INSTANCE, function, vr, nvr, value, nvr));
}

fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Boolean value[]) {
    size_t i;
    BEGIN("fmi2GetBoolean", STATES_GET);
    if (fmu_check_arrays(INSTANCE, function, vr, nvr, value, nvr) != FMU_OK) RETURN(FMU_ERROR);
    for (i = 0; i < nvr; i++) {
        bool b;
        if (fmu_get_boolean(INSTANCE, function, vr[i], &b) != FMU_OK) RETURN(FMU_ERROR);
        value[i] = b ? fmi2True : fmi2False;
    }
    return fmi2OK;
}

fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Boolean value[]) {
    size_t i;
    BEGIN("fmi2SetBoolean", STATES_SET);
    if (fmu_check_arrays(INSTANCE, function, vr, nvr, value, nvr) != FMU_OK) RETURN(FMU_ERROR);
    for (i = 0; i < nvr; i++)
        if (fmu_set_boolean(INSTANCE, function, vr[i], value[i] != fmi2False) != FMU_OK) RETURN(FMU_ERROR);
    return fmi2OK;
}

fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Integer value[]) {
    size_t i;
    BEGIN("fmi2GetInteger", STATES_GET);
    if (fmu_check_arrays(INSTANCE, function, vr, nvr, value, nvr) != FMU_OK) RETURN(FMU_ERROR);
    for (i = 0; i < nvr; i++)
        if (fmu_get_int32(INSTANCE, function, vr[i], &value[i]) != FMU_OK) RETURN(FMU_ERROR);
    return fmi2OK;
}

fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Integer value[]) {
    size_t i;
    BEGIN("fmi2SetInteger", STATES_SET);
    if (fmu_check_arrays(INSTANCE, function, vr, nvr, value, nvr) != FMU_OK) RETURN(FMU_ERROR);
    for (i = 0; i < nvr; i++)
        if (fmu_set_int32(INSTANCE, function, vr[i], value[i]) != FMU_OK) RETURN(FMU_ERROR);
    return fmi2OK;
}

fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2String value[]) {
    size_t i;
    BEGIN("fmi2GetString", STATES_GET);
    if (fmu_check_arrays(INSTANCE, function, vr, nvr, value, nvr) != FMU_OK) RETURN(FMU_ERROR);
    for (i = 0; i < nvr; i++)
        if (fmu_get_string(INSTANCE, function, vr[i], &value[i]) != FMU_OK) RETURN(FMU_ERROR);
    return fmi2OK;
}

fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2String value[]) {
    size_t i;
    BEGIN("fmi2SetString", STATES_SET);
    if (fmu_check_arrays(INSTANCE, function, vr, nvr, value, nvr) != FMU_OK) RETURN(FMU_ERROR);
    for (i = 0; i < nvr; i++)
        if (fmu_set_string(INSTANCE, function, vr[i], value[i]) != FMU_OK) RETURN(FMU_ERROR);
    return fmi2OK;
}

fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *FMUstate) {
    BEGIN("fmi2GetFMUstate", STATES_ANY);
    RETURN(fmu_get_state(INSTANCE, function, FMUstate));
}

fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate FMUstate) {
    BEGIN("fmi2SetFMUstate", STATES_ANY);
    RETURN(fmu_set_state(INSTANCE, function, FMUstate));
}

fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *FMUstate) {
    BEGIN("fmi2FreeFMUstate", STATES_ANY);
    RETURN(fmu_free_state(INSTANCE, function, FMUstate));
}

fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate FMUstate, size_t *size) {
    BEGIN("fmi2SerializedFMUstateSize", STATES_ANY);
    RETURN(fmu_serialized_state_size(INSTANCE, function, FMUstate, size));
}

fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate FMUstate, fmi2Byte serializedState[], size_t size) {
    BEGIN("fmi2SerializeFMUstate", STATES_ANY);
    RETURN(fmu_serialize_state(INSTANCE, function, FMUstate, (unsigned char *)serializedState, size));
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte serializedState[], size_t size,
                                   fmi2FMUstate *FMUstate) {
    BEGIN("fmi2DeSerializeFMUstate", STATES_ANY);
    RETURN(fmu_deserialize_state(INSTANCE, function, (const unsigned char *)serializedState, size, FMUstate));
}

fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference vUnknown_ref[], size_t nUnknown,
                                        const fmi2ValueReference vKnown_ref[], size_t nKnown,
                                        const fmi2Real dvKnown[], fmi2Real dvUnknown[]) {
    BEGIN("fmi2GetDirectionalDerivative", STATES_ANY);
    (void)vUnknown_ref, (void)nUnknown, (void)vKnown_ref, (void)nKnown, (void)dvKnown, (void)dvUnknown;
    RETURN(fmu_unsupported(INSTANCE, function, "providesDirectionalDerivative is false"));
}

/* ---- Co-simulation ---- */

fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                       const fmi2Integer order[], const fmi2Real value[]) {
    BEGIN("fmi2SetRealInputDerivatives", STATES_SET);
    (void)vr, (void)nvr, (void)order, (void)value;
    RETURN(fmu_unsupported(INSTANCE, function, "canInterpolateInputs is false"));
}

fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                        const fmi2Integer order[], fmi2Real value[]) {
    BEGIN("fmi2GetRealOutputDerivatives", STATES_GET);
    (void)vr, (void)nvr, (void)order, (void)value;
    RETURN(fmu_unsupported(INSTANCE, function, "maxOutputDerivativeOrder is 0"));
}

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real currentCommunicationPoint, fmi2Real communicationStepSize,
                      fmi2Boolean noSetFMUStatePriorToCurrentPoint) {
    BEGIN("fmi2DoStep", STATE_STEP_MODE);
    (void)noSetFMUStatePriorToCurrentPoint;
    RETURN(fmu_do_step(INSTANCE, function, currentCommunicationPoint, communicationStepSize));
}

fmi2Status fmi2CancelStep(fmi2Component c) {
    BEGIN("fmi2CancelStep", STATE_STEP_MODE);
    RETURN(fmu_unsupported(INSTANCE, function, "doStep never returns fmi2Pending"));
}

/* The status functions: a status this FMU does not provide is fmi2Discard (FMI 2.0, 4.2.3), which leaves the
 * instance as it was, so the next doStep is still accepted; only a NULL value pointer is an Error. The Discard is
 * logged with debug logging on only: an importer may ask after every step. */
static fmi2Status no_status(FmuInstance *instance, const char *function, const char *why) {
    if (instance->logging_on)
        fmu_log(instance, FMU_DISCARD, "logStatusWarning", "%s: no such status (%s): fmi2Discard", function, why);
    return fmi2Discard;
}

static FmuStatus null_value(FmuInstance *instance, const char *function) {
    fmu_log(instance, FMU_ERROR, "logStatusError", "%s: value is NULL: it must point to where the status goes",
            function);
    return FMU_ERROR;
}

fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind s, fmi2Status *value) {
    BEGIN("fmi2GetStatus", STATES_GET);
    (void)s;
    if (!value) RETURN(null_value(INSTANCE, function));
    return no_status(INSTANCE, function, "doStep never returns fmi2Pending");
}

fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind s, fmi2Real *value) {
    BEGIN("fmi2GetRealStatus", STATES_GET);
    if (!value) RETURN(null_value(INSTANCE, function));
    if (s != fmi2LastSuccessfulTime) return no_status(INSTANCE, function, "only fmi2LastSuccessfulTime");
    *value = INSTANCE->time;
    return fmi2OK;
}

fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind s, fmi2Integer *value) {
    BEGIN("fmi2GetIntegerStatus", STATES_GET);
    (void)s;
    if (!value) RETURN(null_value(INSTANCE, function));
    return no_status(INSTANCE, function, "no integer status");
}

fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind s, fmi2Boolean *value) {
    BEGIN("fmi2GetBooleanStatus", STATES_GET);
    if (!value) RETURN(null_value(INSTANCE, function));
    if (s != fmi2Terminated) return no_status(INSTANCE, function, "only fmi2Terminated");
    *value = fmi2False;
    return fmi2OK;
}

fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind s, fmi2String *value) {
    BEGIN("fmi2GetStringStatus", STATES_GET);
    (void)s;
    if (!value) RETURN(null_value(INSTANCE, function));
    return no_status(INSTANCE, function, "no string status");
}

/* ---- Model exchange: not offered; exported so importers that resolve every symbol can load us ---- */

#define NOT_MODEL_EXCHANGE(name) BEGIN(name, STATES_ANY); RETURN(fmu_unsupported(INSTANCE, function, "co-simulation only"))

fmi2Status fmi2EnterEventMode(fmi2Component c) { NOT_MODEL_EXCHANGE("fmi2EnterEventMode"); }
fmi2Status fmi2NewDiscreteStates(fmi2Component c, fmi2EventInfo *info) {
    (void)info;
    NOT_MODEL_EXCHANGE("fmi2NewDiscreteStates");
}
fmi2Status fmi2EnterContinuousTimeMode(fmi2Component c) { NOT_MODEL_EXCHANGE("fmi2EnterContinuousTimeMode"); }
fmi2Status fmi2CompletedIntegratorStep(fmi2Component c, fmi2Boolean noSetFMUStatePriorToCurrentPoint,
                                       fmi2Boolean *enterEventMode, fmi2Boolean *terminateSimulation) {
    (void)noSetFMUStatePriorToCurrentPoint, (void)enterEventMode, (void)terminateSimulation;
    NOT_MODEL_EXCHANGE("fmi2CompletedIntegratorStep");
}
fmi2Status fmi2SetTime(fmi2Component c, fmi2Real time) {
    (void)time;
    NOT_MODEL_EXCHANGE("fmi2SetTime");
}
fmi2Status fmi2SetContinuousStates(fmi2Component c, const fmi2Real x[], size_t nx) {
    (void)x, (void)nx;
    NOT_MODEL_EXCHANGE("fmi2SetContinuousStates");
}
fmi2Status fmi2GetDerivatives(fmi2Component c, fmi2Real derivatives[], size_t nx) {
    (void)derivatives, (void)nx;
    NOT_MODEL_EXCHANGE("fmi2GetDerivatives");
}
fmi2Status fmi2GetEventIndicators(fmi2Component c, fmi2Real eventIndicators[], size_t ni) {
    (void)eventIndicators, (void)ni;
    NOT_MODEL_EXCHANGE("fmi2GetEventIndicators");
}
fmi2Status fmi2GetContinuousStates(fmi2Component c, fmi2Real x[], size_t nx) {
    (void)x, (void)nx;
    NOT_MODEL_EXCHANGE("fmi2GetContinuousStates");
}
fmi2Status fmi2GetNominalsOfContinuousStates(fmi2Component c, fmi2Real x_nominal[], size_t nx) {
    (void)x_nominal, (void)nx;
    NOT_MODEL_EXCHANGE("fmi2GetNominalsOfContinuousStates");
}
