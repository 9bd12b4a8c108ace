/* The FMI 2.0 interface of hypa's exported step, co-simulation and model exchange (hypa.export.native).

One compilation unit: this file includes step.c (hypa_step: y[k] and state[k+1] from state[k] and u[k], SI)
and model.h (the GUID, dt, the start time, the initial state, the inputs' start values, the parameters). The
step is a discrete-time system on the grid t_k = startTime + k dt:

  co-simulation   fmi2DoStep(t, h) advances h / dt samples (h a whole multiple of dt), the inputs held;
  model exchange  no continuous states; the event iteration at t_k latches state[k+1] from state[k] and the
                  inputs at t_k (sample and hold), the one at t_{k+1} makes it the state; each asks for the
                  next time event. Over [t_k, t_{k+1}) the state is state[k], as in co-simulation.

The outputs are y = hypa_step(state, u) at the current state and inputs (direct feedthrough), computed once
per state and inputs. Value references: the inputs, the outputs, initial_state[1..r], parameter.*, in this
order from 0. Names of this file: fmu_*, FMU_*; step.c's: hypa_step, HYPA_*. */

#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <string.h>

#include "fmi2Functions.h"
#include "step.c"
#include "model.h"

#if HYPA_STATE_SIZE != FMU_STATE_SIZE || HYPA_INPUT_SIZE != FMU_INPUT_SIZE || HYPA_OUTPUT_SIZE != FMU_OUTPUT_SIZE
#error "step.c and model.h disagree on the sizes of the state, the inputs or the outputs"
#endif

#define FMU_BUFFER(n) ((n) > 0 ? (n) : 1) /* C99 has no arrays of size 0 */
#define FMU_EVENT_TOLERANCE 1e-6          /* of dt: a time this close to t_k is t_k */
#define FMU_STEP_TOLERANCE 1e-9           /* of h: fmi2DoStep's h is a whole multiple of dt to this */

#if defined(__GNUC__)
#define FMU_PRINTF(f, a) __attribute__((format(printf, f, a)))
#else
#define FMU_PRINTF(f, a)
#endif

/* the modes of FMI 2.0's state machines, as bits */
enum { FMU_INSTANTIATED = 1, FMU_INITIALIZATION = 2, FMU_STEP_COMPLETE = 4, FMU_EVENT = 8, FMU_CONTINUOUS = 16,
       FMU_TERMINATED = 32 };
#define FMU_RUNNING (FMU_STEP_COMPLETE | FMU_EVENT | FMU_CONTINUOUS)
#define FMU_ANY 63

/* the blocks of value references */
enum { FMU_INPUT, FMU_OUTPUT, FMU_INITIAL_STATE, FMU_PARAMETER, FMU_UNKNOWN };
static const fmi2ValueReference fmu_block_start[] = {
    0, FMU_INPUT_SIZE, FMU_INPUT_SIZE + FMU_OUTPUT_SIZE, FMU_INPUT_SIZE + FMU_OUTPUT_SIZE + FMU_STATE_SIZE,
    FMU_INPUT_SIZE + FMU_OUTPUT_SIZE + FMU_STATE_SIZE + FMU_PARAMETER_COUNT};

typedef struct {
    fmi2CallbackLogger logger;
    fmi2CallbackFreeMemory free_memory;
    fmi2ComponentEnvironment environment;
    char *name;
    fmi2Type type;
    int mode;
    fmi2Real start_time;          /* s: the origin of the sample grid */
    fmi2Real time;                /* s */
    unsigned long long samples;   /* the samples advanced since the start: state = state[samples] */
    int fresh;                    /* next and y hold hypa_step(state, u) */
    int latched;                  /* model exchange: held holds state[samples + 1] */
    fmi2Real u[FMU_BUFFER(FMU_INPUT_SIZE)];
    fmi2Real x0[FMU_BUFFER(FMU_STATE_SIZE)];
    fmi2Real state[FMU_BUFFER(FMU_STATE_SIZE)];
    fmi2Real next[FMU_BUFFER(FMU_STATE_SIZE)];
    fmi2Real held[FMU_BUFFER(FMU_STATE_SIZE)];
    fmi2Real y[FMU_BUFFER(FMU_OUTPUT_SIZE)];
} FmuInstance;

/* Log an error through the importer's logger (the message formatted here: loggers need not expand it). */
static FMU_PRINTF(4, 5) fmi2Status fmu_report(fmi2CallbackLogger logger, fmi2ComponentEnvironment environment,
                                              fmi2String name, const char *format, ...) {
    char message[512];
    va_list args;
    size_t i;
    if (logger == NULL) return fmi2Error;
    va_start(args, format);
    vsnprintf(message, sizeof message, format, args);
    va_end(args);
    for (i = 0; message[i] != '\0'; i++)
        if (message[i] == '%') message[i] = ' ';
    logger(environment, name, fmi2Error, "logStatusError", message);
    return fmi2Error;
}

#define FMU_FAIL(inst, ...) fmu_report((inst)->logger, (inst)->environment, (inst)->name, __VA_ARGS__)

static const char *fmu_mode_name(int mode) {
    switch (mode) {
    case FMU_INSTANTIATED: return "instantiated";
    case FMU_INITIALIZATION: return "initialization mode";
    case FMU_STEP_COMPLETE: return "step complete";
    case FMU_EVENT: return "event mode";
    case FMU_CONTINUOUS: return "continuous-time mode";
    default: return "terminated";
    }
}

/* Whether the instance is in one of the modes; an error through the logger otherwise. */
static int fmu_allowed(FmuInstance *inst, const char *function, int modes) {
    if (inst == NULL) return 0;
    if (inst->mode & modes) return 1;
    FMU_FAIL(inst, "%s is not allowed in this state of the %s instance (%s)", function,
             inst->type == fmi2CoSimulation ? "co-simulation" : "model exchange", fmu_mode_name(inst->mode));
    return 0;
}

/* The block a value reference is in, and its index there. */
static int fmu_block(fmi2ValueReference vr, size_t *index) {
    int block;
    for (block = FMU_INPUT; block < FMU_UNKNOWN; block++) {
        if (vr >= fmu_block_start[block] && vr < fmu_block_start[block + 1]) {
            *index = vr - fmu_block_start[block];
            return block;
        }
    }
    return FMU_UNKNOWN;
}

static fmi2Real fmu_sample_time(const FmuInstance *inst, unsigned long long k) {
    return inst->start_time + (fmi2Real)k * FMU_DT;
}

/* Model exchange: whether the time is at or past the next sample's, t_{k+1}. */
static int fmu_due(const FmuInstance *inst) {
    return inst->time >= fmu_sample_time(inst, inst->samples + 1) - FMU_EVENT_TOLERANCE * FMU_DT;
}

/* next and y from the state and the inputs now, once per state and inputs. */
static void fmu_evaluate(FmuInstance *inst) {
    if (!inst->fresh) {
        hypa_step(inst->state, inst->u, inst->next, inst->y);
        inst->fresh = 1;
    }
}

/* One sample: state := next. */
static void fmu_advance(FmuInstance *inst) {
    fmu_evaluate(inst);
    memcpy(inst->state, inst->next, sizeof inst->state);
    inst->samples++;
    inst->fresh = 0;
}

/* The start values, as fmi2Instantiate leaves them. */
static void fmu_restart(FmuInstance *inst) {
    memcpy(inst->u, fmu_input_start, sizeof inst->u);
    memcpy(inst->x0, fmu_initial_state, sizeof inst->x0);
    memcpy(inst->state, fmu_initial_state, sizeof inst->state);
    inst->start_time = inst->time = FMU_START_TIME;
    inst->samples = 0;
    inst->fresh = 0;
    inst->latched = 0;
    inst->mode = FMU_INSTANTIATED;
}

static fmi2Status fmu_unsupported(fmi2Component c, const char *function) {
    FmuInstance *inst = (FmuInstance *)c;
    if (inst != NULL) FMU_FAIL(inst, "%s is not supported by this FMU", function);
    return fmi2Error;
}

/* Integer, Boolean and String: the FMU has none. */
static fmi2Status fmu_no_variables(fmi2Component c, const char *function, const fmi2ValueReference vr[],
                                   size_t nvr) {
    FmuInstance *inst = (FmuInstance *)c;
    if (inst == NULL) return fmi2Error;
    if (nvr == 0) return fmi2OK;
    return FMU_FAIL(inst, "%s: value reference %lu is unknown: the FMU has Real variables only", function,
                    (unsigned long)vr[0]);
}

/* ---- common functions ---- */

const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }

const char *fmi2GetVersion(void) { return fmi2Version; }

fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean loggingOn, size_t nCategories,
                               const fmi2String categories[]) {
    (void)loggingOn;
    (void)nCategories;
    (void)categories;
    return fmu_allowed((FmuInstance *)c, "fmi2SetDebugLogging", FMU_ANY) ? fmi2OK : fmi2Error;
}

fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                              fmi2String fmuResourceLocation, const fmi2CallbackFunctions *functions,
                              fmi2Boolean visible, fmi2Boolean loggingOn) {
    const char *name = instanceName != NULL ? instanceName : "";
    FmuInstance *inst;
    (void)fmuResourceLocation;
    (void)visible;
    (void)loggingOn;
    if (functions == NULL || functions->allocateMemory == NULL || functions->freeMemory == NULL) return NULL;
    if (fmuGUID == NULL || strcmp(fmuGUID, FMU_GUID) != 0) {
        fmu_report(functions->logger, functions->componentEnvironment, name,
                   "fmi2Instantiate: the GUID %s is not this FMU's, %s", fmuGUID != NULL ? fmuGUID : "(none)",
                   FMU_GUID);
        return NULL;
    }
    if (fmuType != fmi2ModelExchange && fmuType != fmi2CoSimulation) {
        fmu_report(functions->logger, functions->componentEnvironment, name, "fmi2Instantiate: unknown fmuType");
        return NULL;
    }
    inst = (FmuInstance *)functions->allocateMemory(1, sizeof(FmuInstance));
    if (inst == NULL) return NULL;
    inst->name = (char *)functions->allocateMemory(strlen(name) + 1, 1);
    if (inst->name == NULL) {
        functions->freeMemory(inst);
        return NULL;
    }
    memcpy(inst->name, name, strlen(name) + 1);
    inst->logger = functions->logger;
    inst->free_memory = functions->freeMemory;
    inst->environment = functions->componentEnvironment;
    inst->type = fmuType;
    fmu_restart(inst);
    return inst;
}

void fmi2FreeInstance(fmi2Component c) {
    FmuInstance *inst = (FmuInstance *)c;
    fmi2CallbackFreeMemory free_memory;
    if (inst == NULL) return;
    free_memory = inst->free_memory;
    free_memory(inst->name);
    free_memory(inst);
}

fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean toleranceDefined, fmi2Real tolerance,
                               fmi2Real startTime, fmi2Boolean stopTimeDefined, fmi2Real stopTime) {
    FmuInstance *inst = (FmuInstance *)c;
    (void)toleranceDefined;
    (void)tolerance;
    (void)stopTimeDefined;
    (void)stopTime;
    if (!fmu_allowed(inst, "fmi2SetupExperiment", FMU_INSTANTIATED)) return fmi2Error;
    inst->start_time = inst->time = startTime;
    return fmi2OK;
}

fmi2Status fmi2EnterInitializationMode(fmi2Component c) {
    FmuInstance *inst = (FmuInstance *)c;
    if (!fmu_allowed(inst, "fmi2EnterInitializationMode", FMU_INSTANTIATED)) return fmi2Error;
    inst->mode = FMU_INITIALIZATION;
    return fmi2OK;
}

fmi2Status fmi2ExitInitializationMode(fmi2Component c) {
    FmuInstance *inst = (FmuInstance *)c;
    if (!fmu_allowed(inst, "fmi2ExitInitializationMode", FMU_INITIALIZATION)) return fmi2Error;
    memcpy(inst->state, inst->x0, sizeof inst->state);
    inst->time = inst->start_time;
    inst->samples = 0;
    inst->fresh = 0;
    inst->latched = 0;
    inst->mode = inst->type == fmi2CoSimulation ? FMU_STEP_COMPLETE : FMU_EVENT;
    return fmi2OK;
}

fmi2Status fmi2Terminate(fmi2Component c) {
    FmuInstance *inst = (FmuInstance *)c;
    if (!fmu_allowed(inst, "fmi2Terminate", FMU_RUNNING)) return fmi2Error;
    inst->mode = FMU_TERMINATED;
    return fmi2OK;
}

fmi2Status fmi2Reset(fmi2Component c) {
    FmuInstance *inst = (FmuInstance *)c;
    if (!fmu_allowed(inst, "fmi2Reset", FMU_ANY)) return fmi2Error;
    fmu_restart(inst);
    return fmi2OK;
}

fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Real value[]) {
    FmuInstance *inst = (FmuInstance *)c;
    size_t i, k;
    if (!fmu_allowed(inst, "fmi2GetReal", FMU_ANY)) return fmi2Error;
    for (i = 0; i < nvr; i++) {
        switch (fmu_block(vr[i], &k)) {
        case FMU_INPUT: value[i] = inst->u[k]; break;
        case FMU_OUTPUT: fmu_evaluate(inst); value[i] = inst->y[k]; break;
        case FMU_INITIAL_STATE: value[i] = inst->x0[k]; break;
        case FMU_PARAMETER: value[i] = fmu_parameters[k]; break;
        default: return FMU_FAIL(inst, "fmi2GetReal: unknown value reference %lu", (unsigned long)vr[i]);
        }
    }
    return fmi2OK;
}

fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Real value[]) {
    FmuInstance *inst = (FmuInstance *)c;
    size_t i, k;
    if (!fmu_allowed(inst, "fmi2SetReal", FMU_INSTANTIATED | FMU_INITIALIZATION | FMU_RUNNING)) return fmi2Error;
    for (i = 0; i < nvr; i++) {
        switch (fmu_block(vr[i], &k)) {
        case FMU_INPUT: inst->u[k] = value[i]; break;
        case FMU_INITIAL_STATE:
            if (!(inst->mode & (FMU_INSTANTIATED | FMU_INITIALIZATION)))
                return FMU_FAIL(inst, "fmi2SetReal: initial_state[%lu] is fixed after the initialization",
                                (unsigned long)k + 1);
            inst->x0[k] = inst->state[k] = value[i];
            break;
        default:
            return FMU_FAIL(inst, "fmi2SetReal: value reference %lu is no input or parameter", (unsigned long)vr[i]);
        }
        inst->fresh = 0;
    }
    return fmi2OK;
}

fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Integer value[]) {
    (void)value;
    return fmu_no_variables(c, "fmi2GetInteger", vr, nvr);
}

fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Boolean value[]) {
    (void)value;
    return fmu_no_variables(c, "fmi2GetBoolean", vr, nvr);
}

fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2String value[]) {
    (void)value;
    return fmu_no_variables(c, "fmi2GetString", vr, nvr);
}

fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Integer value[]) {
    (void)value;
    return fmu_no_variables(c, "fmi2SetInteger", vr, nvr);
}

fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Boolean value[]) {
    (void)value;
    return fmu_no_variables(c, "fmi2SetBoolean", vr, nvr);
}

fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2String value[]) {
    (void)value;
    return fmu_no_variables(c, "fmi2SetString", vr, nvr);
}

/* ---- FMU state and directional derivatives: not provided (canGetAndSetFMUstate,
        providesDirectionalDerivative are false) ---- */

fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *FMUstate) {
    (void)FMUstate;
    return fmu_unsupported(c, "fmi2GetFMUstate");
}

fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate FMUstate) {
    (void)FMUstate;
    return fmu_unsupported(c, "fmi2SetFMUstate");
}

fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *FMUstate) {
    (void)FMUstate;
    return fmu_unsupported(c, "fmi2FreeFMUstate");
}

fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate FMUstate, size_t *size) {
    (void)FMUstate;
    (void)size;
    return fmu_unsupported(c, "fmi2SerializedFMUstateSize");
}

fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate FMUstate, fmi2Byte serializedState[],
                                 size_t size) {
    (void)FMUstate;
    (void)serializedState;
    (void)size;
    return fmu_unsupported(c, "fmi2SerializeFMUstate");
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte serializedState[], size_t size,
                                   fmi2FMUstate *FMUstate) {
    (void)serializedState;
    (void)size;
    (void)FMUstate;
    return fmu_unsupported(c, "fmi2DeSerializeFMUstate");
}

fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference vUnknown_ref[], size_t nUnknown,
                                        const fmi2ValueReference vKnown_ref[], size_t nKnown,
                                        const fmi2Real dvKnown[], fmi2Real dvUnknown[]) {
    (void)vUnknown_ref;
    (void)nUnknown;
    (void)vKnown_ref;
    (void)nKnown;
    (void)dvKnown;
    (void)dvUnknown;
    return fmu_unsupported(c, "fmi2GetDirectionalDerivative");
}

/* ---- model exchange: a discrete-time system, updated at the time events t_k ---- */

fmi2Status fmi2EnterEventMode(fmi2Component c) {
    FmuInstance *inst = (FmuInstance *)c;
    if (!fmu_allowed(inst, "fmi2EnterEventMode", FMU_EVENT | FMU_CONTINUOUS)) return fmi2Error;
    inst->mode = FMU_EVENT;
    return fmi2OK;
}

fmi2Status fmi2NewDiscreteStates(fmi2Component c, fmi2EventInfo *eventInfo) {
    FmuInstance *inst = (FmuInstance *)c;
    if (!fmu_allowed(inst, "fmi2NewDiscreteStates", FMU_EVENT)) return fmi2Error;
    if (fmu_due(inst)) { /* t_{k+1}: the state latched at t_k (or, had t_k no event, from the inputs now) */
        if (inst->latched) {
            memcpy(inst->state, inst->held, sizeof inst->state);
            inst->samples++;
            inst->fresh = 0;
        } else {
            fmu_advance(inst);
        }
        inst->latched = 0;
    }
    if (fabs(inst->time - fmu_sample_time(inst, inst->samples)) <= FMU_EVENT_TOLERANCE * FMU_DT) {
        fmu_evaluate(inst); /* t_k: latch state[k+1] from the inputs now, again on each call of the iteration */
        memcpy(inst->held, inst->next, sizeof inst->held);
        inst->latched = 1;
    }
    eventInfo->newDiscreteStatesNeeded = fmi2False;
    eventInfo->terminateSimulation = fmi2False;
    eventInfo->nominalsOfContinuousStatesChanged = fmi2False;
    eventInfo->valuesOfContinuousStatesChanged = fmi2False;
    eventInfo->nextEventTimeDefined = fmi2True;
    eventInfo->nextEventTime = fmu_sample_time(inst, inst->samples + 1);
    return fmi2OK;
}

fmi2Status fmi2EnterContinuousTimeMode(fmi2Component c) {
    FmuInstance *inst = (FmuInstance *)c;
    if (!fmu_allowed(inst, "fmi2EnterContinuousTimeMode", FMU_EVENT)) return fmi2Error;
    inst->mode = FMU_CONTINUOUS;
    return fmi2OK;
}

fmi2Status fmi2CompletedIntegratorStep(fmi2Component c, fmi2Boolean noSetFMUStatePriorToCurrentPoint,
                                       fmi2Boolean *enterEventMode, fmi2Boolean *terminateSimulation) {
    FmuInstance *inst = (FmuInstance *)c;
    (void)noSetFMUStatePriorToCurrentPoint;
    if (!fmu_allowed(inst, "fmi2CompletedIntegratorStep", FMU_CONTINUOUS)) return fmi2Error;
    *enterEventMode = fmu_due(inst) ? fmi2True : fmi2False;
    *terminateSimulation = fmi2False;
    return fmi2OK;
}

fmi2Status fmi2SetTime(fmi2Component c, fmi2Real time) {
    FmuInstance *inst = (FmuInstance *)c;
    if (!fmu_allowed(inst, "fmi2SetTime", FMU_EVENT | FMU_CONTINUOUS)) return fmi2Error;
    inst->time = time;
    return fmi2OK;
}

/* No continuous states and no event indicators: each of these takes n = 0 only. */
static fmi2Status fmu_none(fmi2Component c, const char *function, size_t n) {
    FmuInstance *inst = (FmuInstance *)c;
    if (!fmu_allowed(inst, function, FMU_ANY)) return fmi2Error;
    if (n != 0) return FMU_FAIL(inst, "%s: the FMU has no continuous states and no event indicators, not %lu",
                                function, (unsigned long)n);
    return fmi2OK;
}

fmi2Status fmi2SetContinuousStates(fmi2Component c, const fmi2Real x[], size_t nx) {
    (void)x;
    return fmu_none(c, "fmi2SetContinuousStates", nx);
}

fmi2Status fmi2GetDerivatives(fmi2Component c, fmi2Real derivatives[], size_t nx) {
    (void)derivatives;
    return fmu_none(c, "fmi2GetDerivatives", nx);
}

fmi2Status fmi2GetEventIndicators(fmi2Component c, fmi2Real eventIndicators[], size_t ni) {
    (void)eventIndicators;
    return fmu_none(c, "fmi2GetEventIndicators", ni);
}

fmi2Status fmi2GetContinuousStates(fmi2Component c, fmi2Real x[], size_t nx) {
    (void)x;
    return fmu_none(c, "fmi2GetContinuousStates", nx);
}

fmi2Status fmi2GetNominalsOfContinuousStates(fmi2Component c, fmi2Real x_nominal[], size_t nx) {
    (void)x_nominal;
    return fmu_none(c, "fmi2GetNominalsOfContinuousStates", nx);
}

/* ---- co-simulation ---- */

fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                       const fmi2Integer order[], const fmi2Real value[]) {
    (void)vr;
    (void)nvr;
    (void)order;
    (void)value;
    return fmu_unsupported(c, "fmi2SetRealInputDerivatives");
}

fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                        const fmi2Integer order[], fmi2Real value[]) {
    (void)vr;
    (void)nvr;
    (void)order;
    (void)value;
    return fmu_unsupported(c, "fmi2GetRealOutputDerivatives");
}

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real currentCommunicationPoint, fmi2Real communicationStepSize,
                      fmi2Boolean noSetFMUStatePriorToCurrentPoint) {
    FmuInstance *inst = (FmuInstance *)c;
    fmi2Real h = communicationStepSize, samples = floor(communicationStepSize / FMU_DT + 0.5);
    unsigned long long k, n;
    (void)noSetFMUStatePriorToCurrentPoint;
    if (!fmu_allowed(inst, "fmi2DoStep", FMU_STEP_COMPLETE)) return fmi2Error;
    if (!(samples >= 1.0 && samples <= 1e15 && fabs(h - samples * FMU_DT) <= FMU_STEP_TOLERANCE * h))
        return FMU_FAIL(inst, "fmi2DoStep: the step size %.17g s is not a whole multiple of dt = %.17g s", h,
                        FMU_DT);
    n = (unsigned long long)samples;
    for (k = 0; k < n; k++) fmu_advance(inst);
    inst->time = currentCommunicationPoint + h;
    return fmi2OK;
}

fmi2Status fmi2CancelStep(fmi2Component c) { return fmu_unsupported(c, "fmi2CancelStep"); }

/* fmi2DoStep never returns fmi2Pending: the status a tool asks for is the last successful time's and whether
   the slave terminated (never); the others are discarded. */
fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind s, fmi2Status *value) {
    (void)c;
    (void)s;
    (void)value;
    return fmi2Discard;
}

fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind s, fmi2Real *value) {
    FmuInstance *inst = (FmuInstance *)c;
    if (inst == NULL || s != fmi2LastSuccessfulTime) return fmi2Discard;
    *value = inst->time;
    return fmi2OK;
}

fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind s, fmi2Integer *value) {
    (void)c;
    (void)s;
    (void)value;
    return fmi2Discard;
}

fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind s, fmi2Boolean *value) {
    if (c == NULL || s != fmi2Terminated) return fmi2Discard;
    *value = fmi2False;
    return fmi2OK;
}

fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind s, fmi2String *value) {
    (void)c;
    (void)s;
    (void)value;
    return fmi2Discard;
}
