/* Test fixture: the linear single-track (bicycle) vehicle model of single_track.c as an FMI 2.0 FMU for model
   exchange only, with one event indicator and a counter of the completed integrator steps
   (tests/fmu_fixtures.py writes the model description and model.h and builds this file).

   The model, its variables and value references are single_track's (n_sub is kept, unused: there is no
   co-simulation), plus:
     yaw_limit [rad/s]        tunable parameter; the event indicator z = yaw_rate - yaw_limit;
     request_event_at [s]     tunable parameter; where >= 0, fmi2CompletedIntegratorStep at a time >= it
                              returns *enterEventMode = fmi2True (else fmi2False; negative: never);
     completed_steps [1]      output: the fmi2CompletedIntegratorStep calls since fmi2Instantiate or fmi2Reset.
   Nothing changes at an event (no discrete states). No directional derivatives, no FMU state: those functions,
   and the co-simulation ones, log an error and return fmi2Error (every fmi2Functions.h function is exported).

   model.h (generated) defines FMU_GUID, the value references VR_<name>, the start values START_<name> and the
   states' nominal values NOMINAL_<name>. */

#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <string.h>

#include "fmi2Functions.h"
#include "model.h"

#define N_REAL 19 /* the Real value references 0 to 18, 15 (n_sub, an Integer) not among them */
#define N_STATES 2
#define N_INDICATORS 1

enum { M_INSTANTIATED = 1, M_INITIALIZATION = 2, M_EVENT = 8, M_CONTINUOUS = 16, M_TERMINATED = 32 };
#define M_RUNNING (M_EVENT | M_CONTINUOUS)
#define M_ANY 63

typedef struct {
    fmi2Real time;
    fmi2Real r[N_REAL]; /* every Real variable, by value reference (derivatives and outputs kept current) */
    fmi2Integer n_sub;
} Values;

typedef struct {
    fmi2CallbackFunctions cb;
    char name[128];
    int mode;
    Values s;
} Instance;

static fmi2Status fail(Instance *inst, const char *format, ...) {
    char message[512];
    va_list args;
    if (inst == NULL || inst->cb.logger == NULL) return fmi2Error;
    va_start(args, format);
    vsnprintf(message, sizeof message, format, args);
    va_end(args);
    inst->cb.logger(inst->cb.componentEnvironment, inst->name, fmi2Error, "logStatusError", "%s", message);
    return fmi2Error;
}

static int allowed(Instance *inst, const char *function, int modes) {
    if (inst == NULL) return 0;
    if (inst->mode & modes) return 1;
    fail(inst, "%s is not allowed in this state of the instance (mode %d)", function, inst->mode);
    return 0;
}

/* The derivatives and lateral_acceleration from the states, inputs and parameters in r (as single_track.c). */
static void evaluate(fmi2Real *r) {
    const fmi2Real yaw = r[VR_yaw_rate], beta = r[VR_side_slip], v = r[VR_v];
    const fmi2Real delta_f = r[VR_steering_wheel_angle] / r[VR_steering_ratio], delta_r = r[VR_rear_wheel_angle];
    const fmi2Real fyf = r[VR_cf] * (delta_f - beta - r[VR_lf] * yaw / v);
    const fmi2Real fyr = r[VR_cr] * (delta_r - beta + r[VR_lr] * yaw / v);
    r[VR_der_side_slip] = (fyf + fyr) / (r[VR_m] * v) - yaw;
    r[VR_der_yaw_rate] = (r[VR_lf] * fyf - r[VR_lr] * fyr) / r[VR_Iz];
    r[VR_lateral_acceleration] = v * (r[VR_der_side_slip] + yaw);
}

static void restart(Instance *inst) {
    fmi2Real *r = inst->s.r;
    memset(&inst->s, 0, sizeof inst->s);
    r[VR_yaw_rate] = START_yaw_rate;
    r[VR_side_slip] = START_side_slip;
    r[VR_steering_wheel_angle] = START_steering_wheel_angle;
    r[VR_rear_wheel_angle] = START_rear_wheel_angle;
    r[VR_m] = START_m;
    r[VR_Iz] = START_Iz;
    r[VR_lf] = START_lf;
    r[VR_lr] = START_lr;
    r[VR_cf] = START_cf;
    r[VR_cr] = START_cr;
    r[VR_v] = START_v;
    r[VR_steering_ratio] = START_steering_ratio;
    r[VR_yaw_limit] = START_yaw_limit;
    r[VR_request_event_at] = START_request_event_at;
    r[VR_completed_steps] = 0.0;
    inst->s.n_sub = START_n_sub;
    evaluate(r);
    inst->mode = M_INSTANTIATED;
}

static int is_real(fmi2ValueReference vr) { return vr < N_REAL && vr != VR_n_sub; }

static int is_parameter(fmi2ValueReference vr) {
    return vr == VR_m || vr == VR_Iz || vr == VR_lf || vr == VR_lr || vr == VR_cf || vr == VR_cr || vr == VR_v ||
           vr == VR_steering_ratio || vr == VR_yaw_limit || vr == VR_request_event_at;
}

static int is_state(fmi2ValueReference vr) { return vr == VR_yaw_rate || vr == VR_side_slip; }

/* ---- common functions ---- */

const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }

const char *fmi2GetVersion(void) { return fmi2Version; }

fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean loggingOn, size_t nCategories,
                               const fmi2String categories[]) {
    (void)loggingOn;
    (void)nCategories;
    (void)categories;
    return allowed((Instance *)c, "fmi2SetDebugLogging", M_ANY) ? fmi2OK : fmi2Error;
}

fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                              fmi2String fmuResourceLocation, const fmi2CallbackFunctions *functions,
                              fmi2Boolean visible, fmi2Boolean loggingOn) {
    Instance *inst;
    const char *name = instanceName != NULL ? instanceName : "";
    (void)fmuResourceLocation;
    (void)visible;
    (void)loggingOn;
    if (functions == NULL || functions->allocateMemory == NULL || functions->freeMemory == NULL) return NULL;
    if (fmuGUID == NULL || strcmp(fmuGUID, FMU_GUID) != 0 || fmuType != fmi2ModelExchange) {
        if (functions->logger != NULL)
            functions->logger(functions->componentEnvironment, name, fmi2Error, "logStatusError",
                              fmuType != fmi2ModelExchange ? "fmi2Instantiate: model exchange only"
                                                           : "fmi2Instantiate: wrong GUID");
        return NULL;
    }
    inst = (Instance *)functions->allocateMemory(1, sizeof(Instance));
    if (inst == NULL) return NULL;
    inst->cb = *functions;
    snprintf(inst->name, sizeof inst->name, "%s", name);
    restart(inst);
    return inst;
}

void fmi2FreeInstance(fmi2Component c) {
    Instance *inst = (Instance *)c;
    if (inst != NULL) inst->cb.freeMemory(inst);
}

fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean toleranceDefined, fmi2Real tolerance,
                               fmi2Real startTime, fmi2Boolean stopTimeDefined, fmi2Real stopTime) {
    Instance *inst = (Instance *)c;
    (void)toleranceDefined;
    (void)tolerance;
    (void)stopTimeDefined;
    (void)stopTime;
    if (!allowed(inst, "fmi2SetupExperiment", M_INSTANTIATED)) return fmi2Error;
    inst->s.time = startTime;
    return fmi2OK;
}

fmi2Status fmi2EnterInitializationMode(fmi2Component c) {
    Instance *inst = (Instance *)c;
    if (!allowed(inst, "fmi2EnterInitializationMode", M_INSTANTIATED)) return fmi2Error;
    inst->mode = M_INITIALIZATION;
    return fmi2OK;
}

fmi2Status fmi2ExitInitializationMode(fmi2Component c) {
    Instance *inst = (Instance *)c;
    if (!allowed(inst, "fmi2ExitInitializationMode", M_INITIALIZATION)) return fmi2Error;
    evaluate(inst->s.r);
    inst->mode = M_EVENT;
    return fmi2OK;
}

fmi2Status fmi2Terminate(fmi2Component c) {
    Instance *inst = (Instance *)c;
    if (!allowed(inst, "fmi2Terminate", M_RUNNING)) return fmi2Error;
    inst->mode = M_TERMINATED;
    return fmi2OK;
}

fmi2Status fmi2Reset(fmi2Component c) {
    Instance *inst = (Instance *)c;
    if (!allowed(inst, "fmi2Reset", M_ANY)) return fmi2Error;
    restart(inst);
    return fmi2OK;
}

fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Real value[]) {
    Instance *inst = (Instance *)c;
    size_t i;
    if (!allowed(inst, "fmi2GetReal", M_ANY)) return fmi2Error;
    evaluate(inst->s.r);
    for (i = 0; i < nvr; i++) {
        if (!is_real(vr[i])) return fail(inst, "fmi2GetReal: unknown value reference %u", (unsigned)vr[i]);
        value[i] = inst->s.r[vr[i]];
    }
    return fmi2OK;
}

fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Real value[]) {
    Instance *inst = (Instance *)c;
    const int before = M_INSTANTIATED | M_INITIALIZATION;
    size_t i;
    if (!allowed(inst, "fmi2SetReal", before | M_RUNNING)) return fmi2Error;
    for (i = 0; i < nvr; i++) {
        const fmi2ValueReference ref = vr[i];
        if (ref == VR_steering_wheel_angle || ref == VR_rear_wheel_angle) {
            /* inputs: any time */
        } else if (is_state(ref)) {
            if (!(inst->mode & before))
                return fail(inst, "fmi2SetReal: the states are set before the initialization ends (model exchange: "
                                  "fmi2SetContinuousStates)");
        } else if (is_parameter(ref)) {
            if (!(inst->mode & (before | M_EVENT)))
                return fail(inst, "fmi2SetReal: a tunable parameter is set in event mode, not in continuous-time "
                                  "mode");
            if (!isfinite(value[i]) || ((ref == VR_m || ref == VR_Iz || ref == VR_v || ref == VR_steering_ratio) &&
                                        !(value[i] > 0.0)))
                return fail(inst, "fmi2SetReal: value reference %u takes a finite value (positive for m, Iz, v, "
                                  "steering_ratio), not %g", (unsigned)ref, value[i]);
        } else {
            return fail(inst, "fmi2SetReal: value reference %u is no input, state or parameter", (unsigned)ref);
        }
        inst->s.r[ref] = value[i];
    }
    evaluate(inst->s.r);
    return fmi2OK;
}

fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Integer value[]) {
    Instance *inst = (Instance *)c;
    size_t i;
    if (!allowed(inst, "fmi2GetInteger", M_ANY)) return fmi2Error;
    for (i = 0; i < nvr; i++) {
        if (vr[i] != VR_n_sub) return fail(inst, "fmi2GetInteger: unknown value reference %u", (unsigned)vr[i]);
        value[i] = inst->s.n_sub;
    }
    return fmi2OK;
}

fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Integer value[]) {
    Instance *inst = (Instance *)c;
    size_t i;
    if (!allowed(inst, "fmi2SetInteger", M_INSTANTIATED | M_INITIALIZATION)) return fmi2Error;
    for (i = 0; i < nvr; i++) {
        if (vr[i] != VR_n_sub) return fail(inst, "fmi2SetInteger: unknown value reference %u", (unsigned)vr[i]);
        if (value[i] < 1) return fail(inst, "fmi2SetInteger: n_sub is positive, not %d", (int)value[i]);
        inst->s.n_sub = value[i];
    }
    return fmi2OK;
}

fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Boolean value[]) {
    (void)value;
    return nvr == 0 ? fmi2OK : fail((Instance *)c, "fmi2GetBoolean: no Boolean variable %u", (unsigned)vr[0]);
}

fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Boolean value[]) {
    (void)value;
    return nvr == 0 ? fmi2OK : fail((Instance *)c, "fmi2SetBoolean: no Boolean variable %u", (unsigned)vr[0]);
}

fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2String value[]) {
    (void)value;
    return nvr == 0 ? fmi2OK : fail((Instance *)c, "fmi2GetString: no String variable %u", (unsigned)vr[0]);
}

fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2String value[]) {
    (void)value;
    return nvr == 0 ? fmi2OK : fail((Instance *)c, "fmi2SetString: no String variable %u", (unsigned)vr[0]);
}

/* ---- not offered: the FMU state, directional derivatives ---- */

fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *FMUstate) {
    (void)FMUstate;
    return fail((Instance *)c, "fmi2GetFMUstate: the FMU state is not offered (canGetAndSetFMUstate false)");
}

fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate FMUstate) {
    (void)FMUstate;
    return fail((Instance *)c, "fmi2SetFMUstate: the FMU state is not offered (canGetAndSetFMUstate false)");
}

fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *FMUstate) {
    (void)FMUstate;
    return fail((Instance *)c, "fmi2FreeFMUstate: the FMU state is not offered (canGetAndSetFMUstate false)");
}

fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate FMUstate, size_t *size) {
    (void)FMUstate;
    (void)size;
    return fail((Instance *)c, "fmi2SerializedFMUstateSize: the FMU state is not serializable");
}

fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate FMUstate, fmi2Byte serializedState[],
                                 size_t size) {
    (void)FMUstate;
    (void)serializedState;
    (void)size;
    return fail((Instance *)c, "fmi2SerializeFMUstate: the FMU state is not serializable");
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte serializedState[], size_t size,
                                   fmi2FMUstate *FMUstate) {
    (void)serializedState;
    (void)size;
    (void)FMUstate;
    return fail((Instance *)c, "fmi2DeSerializeFMUstate: the FMU state is not serializable");
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
    return fail((Instance *)c,
                "fmi2GetDirectionalDerivative: no directional derivatives (providesDirectionalDerivative false)");
}

/* ---- model exchange: the event indicator yaw_rate - yaw_limit, the step counter, the requested event ---- */

fmi2Status fmi2EnterEventMode(fmi2Component c) {
    Instance *inst = (Instance *)c;
    if (!allowed(inst, "fmi2EnterEventMode", M_EVENT | M_CONTINUOUS)) return fmi2Error;
    inst->mode = M_EVENT;
    return fmi2OK;
}

fmi2Status fmi2NewDiscreteStates(fmi2Component c, fmi2EventInfo *eventInfo) {
    Instance *inst = (Instance *)c;
    if (!allowed(inst, "fmi2NewDiscreteStates", M_EVENT)) return fmi2Error;
    eventInfo->newDiscreteStatesNeeded = fmi2False;
    eventInfo->terminateSimulation = fmi2False;
    eventInfo->nominalsOfContinuousStatesChanged = fmi2False;
    eventInfo->valuesOfContinuousStatesChanged = fmi2False;
    eventInfo->nextEventTimeDefined = fmi2False;
    eventInfo->nextEventTime = 0.0;
    return fmi2OK;
}

fmi2Status fmi2EnterContinuousTimeMode(fmi2Component c) {
    Instance *inst = (Instance *)c;
    if (!allowed(inst, "fmi2EnterContinuousTimeMode", M_EVENT)) return fmi2Error;
    inst->mode = M_CONTINUOUS;
    return fmi2OK;
}

fmi2Status fmi2CompletedIntegratorStep(fmi2Component c, fmi2Boolean noSetFMUStatePriorToCurrentPoint,
                                       fmi2Boolean *enterEventMode, fmi2Boolean *terminateSimulation) {
    Instance *inst = (Instance *)c;
    fmi2Real at;
    (void)noSetFMUStatePriorToCurrentPoint;
    if (!allowed(inst, "fmi2CompletedIntegratorStep", M_CONTINUOUS)) return fmi2Error;
    if (enterEventMode == NULL || terminateSimulation == NULL)
        return fail(inst, "fmi2CompletedIntegratorStep: enterEventMode and terminateSimulation are NULL");
    inst->s.r[VR_completed_steps] += 1.0;
    at = inst->s.r[VR_request_event_at];
    *enterEventMode = at >= 0.0 && inst->s.time >= at ? fmi2True : fmi2False;
    *terminateSimulation = fmi2False;
    return fmi2OK;
}

fmi2Status fmi2SetTime(fmi2Component c, fmi2Real time) {
    Instance *inst = (Instance *)c;
    if (!allowed(inst, "fmi2SetTime", M_EVENT | M_CONTINUOUS)) return fmi2Error;
    inst->s.time = time;
    return fmi2OK;
}

fmi2Status fmi2SetContinuousStates(fmi2Component c, const fmi2Real x[], size_t nx) {
    Instance *inst = (Instance *)c;
    if (!allowed(inst, "fmi2SetContinuousStates", M_CONTINUOUS)) return fmi2Error;
    if (nx != N_STATES) return fail(inst, "fmi2SetContinuousStates: %d states, not %lu", N_STATES, (unsigned long)nx);
    inst->s.r[VR_yaw_rate] = x[0];
    inst->s.r[VR_side_slip] = x[1];
    evaluate(inst->s.r);
    return fmi2OK;
}

fmi2Status fmi2GetContinuousStates(fmi2Component c, fmi2Real x[], size_t nx) {
    Instance *inst = (Instance *)c;
    if (!allowed(inst, "fmi2GetContinuousStates", M_INITIALIZATION | M_RUNNING)) return fmi2Error;
    if (nx != N_STATES) return fail(inst, "fmi2GetContinuousStates: %d states, not %lu", N_STATES, (unsigned long)nx);
    x[0] = inst->s.r[VR_yaw_rate];
    x[1] = inst->s.r[VR_side_slip];
    return fmi2OK;
}

fmi2Status fmi2GetDerivatives(fmi2Component c, fmi2Real derivatives[], size_t nx) {
    Instance *inst = (Instance *)c;
    if (!allowed(inst, "fmi2GetDerivatives", M_INITIALIZATION | M_RUNNING)) return fmi2Error;
    if (nx != N_STATES) return fail(inst, "fmi2GetDerivatives: %d states, not %lu", N_STATES, (unsigned long)nx);
    evaluate(inst->s.r);
    derivatives[0] = inst->s.r[VR_der_yaw_rate];
    derivatives[1] = inst->s.r[VR_der_side_slip];
    return fmi2OK;
}

fmi2Status fmi2GetNominalsOfContinuousStates(fmi2Component c, fmi2Real x_nominal[], size_t nx) {
    Instance *inst = (Instance *)c;
    if (!allowed(inst, "fmi2GetNominalsOfContinuousStates", M_ANY)) return fmi2Error;
    if (nx != N_STATES)
        return fail(inst, "fmi2GetNominalsOfContinuousStates: %d states, not %lu", N_STATES, (unsigned long)nx);
    x_nominal[0] = NOMINAL_yaw_rate;
    x_nominal[1] = NOMINAL_side_slip;
    return fmi2OK;
}

fmi2Status fmi2GetEventIndicators(fmi2Component c, fmi2Real eventIndicators[], size_t ni) {
    Instance *inst = (Instance *)c;
    if (!allowed(inst, "fmi2GetEventIndicators", M_INITIALIZATION | M_RUNNING)) return fmi2Error;
    if (ni != N_INDICATORS)
        return fail(inst, "fmi2GetEventIndicators: %d event indicator, not %lu", N_INDICATORS, (unsigned long)ni);
    eventIndicators[0] = inst->s.r[VR_yaw_rate] - inst->s.r[VR_yaw_limit];
    return fmi2OK;
}

/* ---- co-simulation: not offered ---- */

fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                       const fmi2Integer order[], const fmi2Real value[]) {
    (void)vr;
    (void)nvr;
    (void)order;
    (void)value;
    return fail((Instance *)c, "fmi2SetRealInputDerivatives: model exchange only");
}

fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                        const fmi2Integer order[], fmi2Real value[]) {
    (void)vr;
    (void)nvr;
    (void)order;
    (void)value;
    return fail((Instance *)c, "fmi2GetRealOutputDerivatives: model exchange only");
}

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real currentCommunicationPoint, fmi2Real communicationStepSize,
                      fmi2Boolean noSetFMUStatePriorToCurrentPoint) {
    (void)currentCommunicationPoint;
    (void)communicationStepSize;
    (void)noSetFMUStatePriorToCurrentPoint;
    return fail((Instance *)c, "fmi2DoStep: model exchange only");
}

fmi2Status fmi2CancelStep(fmi2Component c) { return fail((Instance *)c, "fmi2CancelStep: model exchange only"); }

fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind s, fmi2Status *value) {
    (void)s;
    (void)value;
    return fail((Instance *)c, "fmi2GetStatus: model exchange only");
}

fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind s, fmi2Real *value) {
    (void)s;
    (void)value;
    return fail((Instance *)c, "fmi2GetRealStatus: model exchange only");
}

fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind s, fmi2Integer *value) {
    (void)s;
    (void)value;
    return fail((Instance *)c, "fmi2GetIntegerStatus: model exchange only");
}

fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind s, fmi2Boolean *value) {
    (void)s;
    (void)value;
    return fail((Instance *)c, "fmi2GetBooleanStatus: model exchange only");
}

fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind s, fmi2String *value) {
    (void)s;
    (void)value;
    return fail((Instance *)c, "fmi2GetStringStatus: model exchange only");
}
