/* FMI 3.0 co-simulation entry points, mapped onto the version-independent core (fmu_instance.c). */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi3Functions.h"
#include "fmu_instance.h"

#define INSTANCE ((FmuInstance *)c)

/* Every entry point starts with this: a NULL instance cannot log, so it only returns Error. */
#define BEGIN(name, allowed)                                                                                  \
    static const char *const function = name;                                                                 \
    if (!c) return fmi3Error;                                                                                 \
    if (fmu_check_state(INSTANCE, function, (allowed)) != FMU_OK) return (fmi3Status)fmu_fail(INSTANCE, FMU_ERROR)

#define RETURN(status) return (fmi3Status)fmu_fail(INSTANCE, (status))

static void log_sink(const FmuInstance *instance, FmuStatus status, const char *category, const char *message) {
    fmi3LogMessageCallback logger = (fmi3LogMessageCallback)instance->importer_logger;
    logger(instance->importer_environment, (fmi3Status)status, category, message);
}

const char *fmi3GetVersion(void) { return fmi3Version; }

fmi3Instance fmi3InstantiateCoSimulation(fmi3String instanceName, fmi3String instantiationToken,
                                         fmi3String resourcePath, fmi3Boolean visible, fmi3Boolean loggingOn,
                                         fmi3Boolean eventModeUsed, fmi3Boolean earlyReturnAllowed,
                                         const fmi3ValueReference requiredIntermediateVariables[],
                                         size_t nRequiredIntermediateVariables,
                                         fmi3InstanceEnvironment instanceEnvironment,
                                         fmi3LogMessageCallback logMessage,
                                         fmi3IntermediateUpdateCallback intermediateUpdate) {
    (void)visible, (void)earlyReturnAllowed, (void)requiredIntermediateVariables, (void)intermediateUpdate;
    if (eventModeUsed || nRequiredIntermediateVariables > 0) {
        fmu_log_without_instance(log_sink, (FmuCallback)logMessage, instanceEnvironment, instanceName,
                                 "fmi3InstantiateCoSimulation: event mode and intermediate variables are not "
                                 "supported (hasEventMode = false, providesIntermediateUpdate = false)");
        return NULL;
    }
    return fmu_create("fmi3InstantiateCoSimulation", instanceName, instantiationToken, resourcePath, log_sink,
                      (FmuCallback)logMessage, instanceEnvironment, loggingOn);
}

fmi3Instance fmi3InstantiateModelExchange(fmi3String instanceName, fmi3String instantiationToken,
                                          fmi3String resourcePath, fmi3Boolean visible, fmi3Boolean loggingOn,
                                          fmi3InstanceEnvironment instanceEnvironment,
                                          fmi3LogMessageCallback logMessage) {
    (void)instantiationToken, (void)resourcePath, (void)visible, (void)loggingOn;
    fmu_log_without_instance(log_sink, (FmuCallback)logMessage, instanceEnvironment, instanceName,
                             "fmi3InstantiateModelExchange: this FMU supports co-simulation only");
    return NULL;
}

fmi3Instance fmi3InstantiateScheduledExecution(fmi3String instanceName, fmi3String instantiationToken,
                                               fmi3String resourcePath, fmi3Boolean visible, fmi3Boolean loggingOn,
                                               fmi3InstanceEnvironment instanceEnvironment,
                                               fmi3LogMessageCallback logMessage,
                                               fmi3ClockUpdateCallback clockUpdate,
                                               fmi3LockPreemptionCallback lockPreemption,
                                               fmi3UnlockPreemptionCallback unlockPreemption) {
    (void)instantiationToken, (void)resourcePath, (void)visible, (void)loggingOn, (void)clockUpdate,
        (void)lockPreemption, (void)unlockPreemption;
    fmu_log_without_instance(log_sink, (FmuCallback)logMessage, instanceEnvironment, instanceName,
                             "fmi3InstantiateScheduledExecution: this FMU supports co-simulation only");
    return NULL;
}

void fmi3FreeInstance(fmi3Instance c) { fmu_destroy(INSTANCE); }

fmi3Status fmi3SetDebugLogging(fmi3Instance c, fmi3Boolean loggingOn, size_t nCategories,
                               const fmi3String categories[]) {
    BEGIN("fmi3SetDebugLogging", STATES_ANY);
    RETURN(fmu_set_debug_logging(INSTANCE, loggingOn, nCategories, categories));
}

fmi3Status fmi3EnterInitializationMode(fmi3Instance c, fmi3Boolean toleranceDefined, fmi3Float64 tolerance,
                                       fmi3Float64 startTime, fmi3Boolean stopTimeDefined, fmi3Float64 stopTime) {
    BEGIN("fmi3EnterInitializationMode", STATE_INSTANTIATED);
    (void)toleranceDefined, (void)tolerance;
    RETURN(fmu_enter_initialization(INSTANCE, function, startTime, stopTimeDefined, stopTime));
}

fmi3Status fmi3ExitInitializationMode(fmi3Instance c) {
    BEGIN("fmi3ExitInitializationMode", STATE_INITIALIZATION_MODE);
    RETURN(fmu_exit_initialization(INSTANCE, function));
}

fmi3Status fmi3Terminate(fmi3Instance c) {
    BEGIN("fmi3Terminate", STATE_STEP_MODE);
    RETURN(fmu_terminate(INSTANCE, function));
}

fmi3Status fmi3Reset(fmi3Instance c) {
    BEGIN("fmi3Reset", STATES_ANY);
    return (fmi3Status)fmu_reset(INSTANCE);
}

fmi3Status fmi3GetFloat64(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, fmi3Float64 values[],
                          size_t nValues) {
    BEGIN("fmi3GetFloat64", STATES_GET);
    RETURN(fmu_get_float64s(INSTANCE, function, vr, nvr, values, nValues));
}

fmi3Status fmi3SetFloat64(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, const fmi3Float64 values[],
                          size_t nValues) {
    BEGIN("fmi3SetFloat64", STATES_SET);
    RETURN(fmu_set_float64s(INSTANCE, function, vr, nvr, values, nValues));
}

fmi3Status fmi3GetBoolean(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, fmi3Boolean values[],
                          size_t nValues) {
    size_t i;
    BEGIN("fmi3GetBoolean", STATES_GET);
    if (fmu_check_arrays(INSTANCE, function, vr, nvr, values, nValues) != FMU_OK) RETURN(FMU_ERROR);
    for (i = 0; i < nvr; i++)
        if (fmu_get_boolean(INSTANCE, function, vr[i], &values[i]) != FMU_OK) RETURN(FMU_ERROR);
    return fmi3OK;
}

fmi3Status fmi3SetBoolean(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, const fmi3Boolean values[],
                          size_t nValues) {
    size_t i;
    BEGIN("fmi3SetBoolean", STATES_SET);
    if (fmu_check_arrays(INSTANCE, function, vr, nvr, values, nValues) != FMU_OK) RETURN(FMU_ERROR);
    for (i = 0; i < nvr; i++)
        if (fmu_set_boolean(INSTANCE, function, vr[i], values[i]) != FMU_OK) RETURN(FMU_ERROR);
    return fmi3OK;
}

fmi3Status fmi3GetInt32(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, fmi3Int32 values[],
                        size_t nValues) {
    size_t i;
    BEGIN("fmi3GetInt32", STATES_GET);
    if (fmu_check_arrays(INSTANCE, function, vr, nvr, values, nValues) != FMU_OK) RETURN(FMU_ERROR);
    for (i = 0; i < nvr; i++)
        if (fmu_get_int32(INSTANCE, function, vr[i], &values[i]) != FMU_OK) RETURN(FMU_ERROR);
    return fmi3OK;
}

fmi3Status fmi3SetInt32(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, const fmi3Int32 values[],
                        size_t nValues) {
    size_t i;
    BEGIN("fmi3SetInt32", STATES_SET);
    if (fmu_check_arrays(INSTANCE, function, vr, nvr, values, nValues) != FMU_OK) RETURN(FMU_ERROR);
    for (i = 0; i < nvr; i++)
        if (fmu_set_int32(INSTANCE, function, vr[i], values[i]) != FMU_OK) RETURN(FMU_ERROR);
    return fmi3OK;
}

fmi3Status fmi3GetString(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, fmi3String values[],
                         size_t nValues) {
    size_t i;
    BEGIN("fmi3GetString", STATES_GET);
    if (fmu_check_arrays(INSTANCE, function, vr, nvr, values, nValues) != FMU_OK) RETURN(FMU_ERROR);
    for (i = 0; i < nvr; i++)
        if (fmu_get_string(INSTANCE, function, vr[i], &values[i]) != FMU_OK) RETURN(FMU_ERROR);
    return fmi3OK;
}

fmi3Status fmi3SetString(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, const fmi3String values[],
                         size_t nValues) {
    size_t i;
    BEGIN("fmi3SetString", STATES_SET);
    if (fmu_check_arrays(INSTANCE, function, vr, nvr, values, nValues) != FMU_OK) RETURN(FMU_ERROR);
    for (i = 0; i < nvr; i++)
        if (fmu_set_string(INSTANCE, function, vr[i], values[i]) != FMU_OK) RETURN(FMU_ERROR);
    return fmi3OK;
}

/* The models have only Float64, Int32, Boolean and String variables: any value reference of another type is unknown. */
#define REJECT_GET(Name, T)                                                                                   \
    fmi3Status fmi3Get##Name(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, T values[], size_t nValues) { \
        BEGIN("fmi3Get" #Name, STATES_GET);                                                                   \
        (void)vr, (void)values, (void)nValues;                                                                \
        RETURN(fmu_reject_type(INSTANCE, function, #Name, nvr));                                              \
    }
#define REJECT_SET(Name, T)                                                                                   \
    fmi3Status fmi3Set##Name(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, const T values[],       \
                             size_t nValues) {                                                                \
        BEGIN("fmi3Set" #Name, STATES_SET);                                                                   \
        (void)vr, (void)values, (void)nValues;                                                                \
        RETURN(fmu_reject_type(INSTANCE, function, #Name, nvr));                                              \
    }
#define REJECT_GET_SET(Name, T) REJECT_GET(Name, T) REJECT_SET(Name, T)

REJECT_GET_SET(Float32, fmi3Float32)
REJECT_GET_SET(Int8, fmi3Int8)
REJECT_GET_SET(UInt8, fmi3UInt8)
REJECT_GET_SET(Int16, fmi3Int16)
REJECT_GET_SET(UInt16, fmi3UInt16)
REJECT_GET_SET(UInt32, fmi3UInt32)
REJECT_GET_SET(Int64, fmi3Int64)
REJECT_GET_SET(UInt64, fmi3UInt64)

fmi3Status fmi3GetBinary(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, size_t valueSizes[],
                         fmi3Binary values[], size_t nValues) {
    BEGIN("fmi3GetBinary", STATES_GET);
    (void)vr, (void)valueSizes, (void)values, (void)nValues;
    RETURN(fmu_reject_type(INSTANCE, function, "Binary", nvr));
}

fmi3Status fmi3SetBinary(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, const size_t valueSizes[],
                         const fmi3Binary values[], size_t nValues) {
    BEGIN("fmi3SetBinary", STATES_SET);
    (void)vr, (void)valueSizes, (void)values, (void)nValues;
    RETURN(fmu_reject_type(INSTANCE, function, "Binary", nvr));
}

fmi3Status fmi3GetClock(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, fmi3Clock values[]) {
    BEGIN("fmi3GetClock", STATES_GET);
    (void)vr, (void)values;
    RETURN(fmu_reject_type(INSTANCE, function, "Clock", nvr));
}

fmi3Status fmi3SetClock(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, const fmi3Clock values[]) {
    BEGIN("fmi3SetClock", STATES_SET);
    (void)vr, (void)values;
    RETURN(fmu_reject_type(INSTANCE, function, "Clock", nvr));
}

fmi3Status fmi3GetFMUState(fmi3Instance c, fmi3FMUState *FMUState) {
    BEGIN("fmi3GetFMUState", STATES_ANY);
    RETURN(fmu_get_state(INSTANCE, function, FMUState));
}

fmi3Status fmi3SetFMUState(fmi3Instance c, fmi3FMUState FMUState) {
    BEGIN("fmi3SetFMUState", STATES_ANY);
    RETURN(fmu_set_state(INSTANCE, function, FMUState));
}

fmi3Status fmi3FreeFMUState(fmi3Instance c, fmi3FMUState *FMUState) {
    BEGIN("fmi3FreeFMUState", STATES_ANY);
    RETURN(fmu_free_state(INSTANCE, function, FMUState));
}

fmi3Status fmi3SerializedFMUStateSize(fmi3Instance c, fmi3FMUState FMUState, size_t *size) {
    BEGIN("fmi3SerializedFMUStateSize", STATES_ANY);
    RETURN(fmu_serialized_state_size(INSTANCE, function, FMUState, size));
}

fmi3Status fmi3SerializeFMUState(fmi3Instance c, fmi3FMUState FMUState, fmi3Byte serializedState[], size_t size) {
    BEGIN("fmi3SerializeFMUState", STATES_ANY);
    RETURN(fmu_serialize_state(INSTANCE, function, FMUState, serializedState, size));
}

fmi3Status fmi3DeserializeFMUState(fmi3Instance c, const fmi3Byte serializedState[], size_t size,
                                   fmi3FMUState *FMUState) {
    BEGIN("fmi3DeserializeFMUState", STATES_ANY);
    RETURN(fmu_deserialize_state(INSTANCE, function, serializedState, size, FMUState));
}

fmi3Status fmi3DoStep(fmi3Instance c, fmi3Float64 currentCommunicationPoint, fmi3Float64 communicationStepSize,
                      fmi3Boolean noSetFMUStatePriorToCurrentPoint, fmi3Boolean *eventHandlingNeeded,
                      fmi3Boolean *terminateSimulation, fmi3Boolean *earlyReturn, fmi3Float64 *lastSuccessfulTime) {
    FmuStatus status;
    BEGIN("fmi3DoStep", STATE_STEP_MODE);
    (void)noSetFMUStatePriorToCurrentPoint;
    if (!eventHandlingNeeded || !terminateSimulation || !earlyReturn || !lastSuccessfulTime) {
        fmu_log(INSTANCE, FMU_ERROR, "logStatusError",
                "%s: eventHandlingNeeded, terminateSimulation, earlyReturn and lastSuccessfulTime must not be NULL",
                function);
        RETURN(FMU_ERROR);
    }
    status = fmu_do_step(INSTANCE, function, currentCommunicationPoint, communicationStepSize);
    *eventHandlingNeeded = fmi3False;
    *terminateSimulation = fmi3False;
    *earlyReturn = fmi3False;
    *lastSuccessfulTime = INSTANCE->time;
    RETURN(status);
}

/* ---- Not offered by these FMUs (see the capability flags in the model description) ---- */

#define UNSUPPORTED(name, allowed, why) BEGIN(name, allowed); RETURN(fmu_unsupported(INSTANCE, function, why))

fmi3Status fmi3EnterEventMode(fmi3Instance c) { UNSUPPORTED("fmi3EnterEventMode", STATES_ANY, "hasEventMode is false"); }
fmi3Status fmi3EnterStepMode(fmi3Instance c) { UNSUPPORTED("fmi3EnterStepMode", STATES_ANY, "hasEventMode is false"); }

fmi3Status fmi3GetNumberOfVariableDependencies(fmi3Instance c, fmi3ValueReference valueReference,
                                               size_t *nDependencies) {
    (void)valueReference, (void)nDependencies;
    UNSUPPORTED("fmi3GetNumberOfVariableDependencies", STATES_ANY, "providesPerElementDependencies is false");
}

fmi3Status fmi3GetVariableDependencies(fmi3Instance c, fmi3ValueReference dependent,
                                       size_t elementIndicesOfDependent[], fmi3ValueReference independents[],
                                       size_t elementIndicesOfIndependents[], fmi3DependencyKind dependencyKinds[],
                                       size_t nDependencies) {
    (void)dependent, (void)elementIndicesOfDependent, (void)independents, (void)elementIndicesOfIndependents,
        (void)dependencyKinds, (void)nDependencies;
    UNSUPPORTED("fmi3GetVariableDependencies", STATES_ANY, "providesPerElementDependencies is false");
}

fmi3Status fmi3GetDirectionalDerivative(fmi3Instance c, const fmi3ValueReference unknowns[], size_t nUnknowns,
                                        const fmi3ValueReference knowns[], size_t nKnowns, const fmi3Float64 seed[],
                                        size_t nSeed, fmi3Float64 sensitivity[], size_t nSensitivity) {
    (void)unknowns, (void)nUnknowns, (void)knowns, (void)nKnowns, (void)seed, (void)nSeed, (void)sensitivity,
        (void)nSensitivity;
    UNSUPPORTED("fmi3GetDirectionalDerivative", STATES_ANY, "providesDirectionalDerivatives is false");
}

fmi3Status fmi3GetAdjointDerivative(fmi3Instance c, const fmi3ValueReference unknowns[], size_t nUnknowns,
                                    const fmi3ValueReference knowns[], size_t nKnowns, const fmi3Float64 seed[],
                                    size_t nSeed, fmi3Float64 sensitivity[], size_t nSensitivity) {
    (void)unknowns, (void)nUnknowns, (void)knowns, (void)nKnowns, (void)seed, (void)nSeed, (void)sensitivity,
        (void)nSensitivity;
    UNSUPPORTED("fmi3GetAdjointDerivative", STATES_ANY, "providesAdjointDerivatives is false");
}

fmi3Status fmi3EnterConfigurationMode(fmi3Instance c) {
    UNSUPPORTED("fmi3EnterConfigurationMode", STATES_ANY, "no structural parameters");
}
fmi3Status fmi3ExitConfigurationMode(fmi3Instance c) {
    UNSUPPORTED("fmi3ExitConfigurationMode", STATES_ANY, "no structural parameters");
}

fmi3Status fmi3GetIntervalDecimal(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, fmi3Float64 intervals[],
                                  fmi3IntervalQualifier qualifiers[]) {
    (void)vr, (void)nvr, (void)intervals, (void)qualifiers;
    UNSUPPORTED("fmi3GetIntervalDecimal", STATES_ANY, "no clocks");
}
fmi3Status fmi3GetIntervalFraction(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, fmi3UInt64 counters[],
                                   fmi3UInt64 resolutions[], fmi3IntervalQualifier qualifiers[]) {
    (void)vr, (void)nvr, (void)counters, (void)resolutions, (void)qualifiers;
    UNSUPPORTED("fmi3GetIntervalFraction", STATES_ANY, "no clocks");
}
fmi3Status fmi3GetShiftDecimal(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, fmi3Float64 shifts[]) {
    (void)vr, (void)nvr, (void)shifts;
    UNSUPPORTED("fmi3GetShiftDecimal", STATES_ANY, "no clocks");
}
fmi3Status fmi3GetShiftFraction(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, fmi3UInt64 counters[],
                                fmi3UInt64 resolutions[]) {
    (void)vr, (void)nvr, (void)counters, (void)resolutions;
    UNSUPPORTED("fmi3GetShiftFraction", STATES_ANY, "no clocks");
}
fmi3Status fmi3SetIntervalDecimal(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr,
                                  const fmi3Float64 intervals[]) {
    (void)vr, (void)nvr, (void)intervals;
    UNSUPPORTED("fmi3SetIntervalDecimal", STATES_ANY, "no clocks");
}
fmi3Status fmi3SetIntervalFraction(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr,
                                   const fmi3UInt64 counters[], const fmi3UInt64 resolutions[]) {
    (void)vr, (void)nvr, (void)counters, (void)resolutions;
    UNSUPPORTED("fmi3SetIntervalFraction", STATES_ANY, "no clocks");
}
fmi3Status fmi3SetShiftDecimal(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, const fmi3Float64 shifts[]) {
    (void)vr, (void)nvr, (void)shifts;
    UNSUPPORTED("fmi3SetShiftDecimal", STATES_ANY, "no clocks");
}
fmi3Status fmi3SetShiftFraction(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr,
                                const fmi3UInt64 counters[], const fmi3UInt64 resolutions[]) {
    (void)vr, (void)nvr, (void)counters, (void)resolutions;
    UNSUPPORTED("fmi3SetShiftFraction", STATES_ANY, "no clocks");
}
fmi3Status fmi3ActivateModelPartition(fmi3Instance c, fmi3ValueReference clockReference,
                                      fmi3Float64 activationTime) {
    (void)clockReference, (void)activationTime;
    UNSUPPORTED("fmi3ActivateModelPartition", STATES_ANY, "no clocks");
}

fmi3Status fmi3EvaluateDiscreteStates(fmi3Instance c) {
    UNSUPPORTED("fmi3EvaluateDiscreteStates", STATES_ANY, "hasEventMode is false");
}
fmi3Status fmi3UpdateDiscreteStates(fmi3Instance c, fmi3Boolean *discreteStatesNeedUpdate,
                                    fmi3Boolean *terminateSimulation, fmi3Boolean *nominalsOfContinuousStatesChanged,
                                    fmi3Boolean *valuesOfContinuousStatesChanged, fmi3Boolean *nextEventTimeDefined,
                                    fmi3Float64 *nextEventTime) {
    (void)discreteStatesNeedUpdate, (void)terminateSimulation, (void)nominalsOfContinuousStatesChanged,
        (void)valuesOfContinuousStatesChanged, (void)nextEventTimeDefined, (void)nextEventTime;
    UNSUPPORTED("fmi3UpdateDiscreteStates", STATES_ANY, "hasEventMode is false");
}

fmi3Status fmi3GetOutputDerivatives(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr,
                                    const fmi3Int32 orders[], fmi3Float64 values[], size_t nValues) {
    (void)vr, (void)nvr, (void)orders, (void)values, (void)nValues;
    UNSUPPORTED("fmi3GetOutputDerivatives", STATES_ANY, "maxOutputDerivativeOrder is 0");
}

/* Model exchange functions: exported so importers that resolve every symbol can load us. */
fmi3Status fmi3EnterContinuousTimeMode(fmi3Instance c) {
    UNSUPPORTED("fmi3EnterContinuousTimeMode", STATES_ANY, "co-simulation only");
}
fmi3Status fmi3CompletedIntegratorStep(fmi3Instance c, fmi3Boolean noSetFMUStatePriorToCurrentPoint,
                                       fmi3Boolean *enterEventMode, fmi3Boolean *terminateSimulation) {
    (void)noSetFMUStatePriorToCurrentPoint, (void)enterEventMode, (void)terminateSimulation;
    UNSUPPORTED("fmi3CompletedIntegratorStep", STATES_ANY, "co-simulation only");
}
fmi3Status fmi3SetTime(fmi3Instance c, fmi3Float64 time) {
    (void)time;
    UNSUPPORTED("fmi3SetTime", STATES_ANY, "co-simulation only");
}
fmi3Status fmi3SetContinuousStates(fmi3Instance c, const fmi3Float64 continuousStates[], size_t n) {
    (void)continuousStates, (void)n;
    UNSUPPORTED("fmi3SetContinuousStates", STATES_ANY, "co-simulation only");
}
fmi3Status fmi3GetContinuousStateDerivatives(fmi3Instance c, fmi3Float64 derivatives[], size_t n) {
    (void)derivatives, (void)n;
    UNSUPPORTED("fmi3GetContinuousStateDerivatives", STATES_ANY, "co-simulation only");
}
fmi3Status fmi3GetEventIndicators(fmi3Instance c, fmi3Float64 eventIndicators[], size_t n) {
    (void)eventIndicators, (void)n;
    UNSUPPORTED("fmi3GetEventIndicators", STATES_ANY, "co-simulation only");
}
fmi3Status fmi3GetContinuousStates(fmi3Instance c, fmi3Float64 continuousStates[], size_t n) {
    (void)continuousStates, (void)n;
    UNSUPPORTED("fmi3GetContinuousStates", STATES_ANY, "co-simulation only");
}
fmi3Status fmi3GetNominalsOfContinuousStates(fmi3Instance c, fmi3Float64 nominals[], size_t n) {
    (void)nominals, (void)n;
    UNSUPPORTED("fmi3GetNominalsOfContinuousStates", STATES_ANY, "co-simulation only");
}
fmi3Status fmi3GetNumberOfEventIndicators(fmi3Instance c, size_t *n) {
    (void)n;
    UNSUPPORTED("fmi3GetNumberOfEventIndicators", STATES_ANY, "co-simulation only");
}
fmi3Status fmi3GetNumberOfContinuousStates(fmi3Instance c, size_t *n) {
    (void)n;
    UNSUPPORTED("fmi3GetNumberOfContinuousStates", STATES_ANY, "co-simulation only");
}
