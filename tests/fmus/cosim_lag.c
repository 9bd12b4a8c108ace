/* Test fixture: a first-order lag as an FMI 2.0 co-simulation FMU (no model exchange, no directional
   derivatives, no FMU state). tests/fmu_fixtures.py writes the model description and model.h and builds it.

     dy/dt = (K u - y) / tau

   fmi2DoStep(t, h) integrates it exactly over any h >= 0 with the input u held:
     y(t + h) = K u + (y(t) - K u) exp(-h / tau).
   y is an output with initial="exact": it may be set before the initialization ends (the start of the lag).

   model.h (generated) defines FMU_GUID, the value references VR_<name> and the start values START_<name>. */

#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <string.h>

#include "fmi2Functions.h"
#include "model.h"

#define N_REAL 4

enum { M_INSTANTIATED = 1, M_INITIALIZATION = 2, M_STEP_COMPLETE = 4, M_TERMINATED = 8 };
#define M_ANY 15

typedef struct {
    fmi2CallbackFunctions cb;
    char name[128];
    int mode;
    fmi2Real time;
    fmi2Real r[N_REAL]; /* by value reference */
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

static void restart(Instance *inst) {
    inst->time = 0.0;
    inst->r[VR_u] = START_u;
    inst->r[VR_y] = START_y;
    inst->r[VR_K] = START_K;
    inst->r[VR_tau] = START_tau;
    inst->mode = M_INSTANTIATED;
}

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
    (void)fmuResourceLocation;
    (void)visible;
    (void)loggingOn;
    if (functions == NULL || functions->allocateMemory == NULL || functions->freeMemory == NULL) return NULL;
    if (fmuGUID == NULL || strcmp(fmuGUID, FMU_GUID) != 0 || fmuType != fmi2CoSimulation) return NULL;
    inst = (Instance *)functions->allocateMemory(1, sizeof(Instance));
    if (inst == NULL) return NULL;
    inst->cb = *functions;
    snprintf(inst->name, sizeof inst->name, "%s", instanceName != NULL ? instanceName : "");
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
    inst->time = startTime;
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
    inst->mode = M_STEP_COMPLETE;
    return fmi2OK;
}

fmi2Status fmi2Terminate(fmi2Component c) {
    Instance *inst = (Instance *)c;
    if (!allowed(inst, "fmi2Terminate", M_STEP_COMPLETE)) return fmi2Error;
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
    for (i = 0; i < nvr; i++) {
        if (vr[i] >= N_REAL) return fail(inst, "fmi2GetReal: unknown value reference %u", (unsigned)vr[i]);
        value[i] = inst->r[vr[i]];
    }
    return fmi2OK;
}

fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Real value[]) {
    Instance *inst = (Instance *)c;
    const int before = M_INSTANTIATED | M_INITIALIZATION;
    size_t i;
    if (!allowed(inst, "fmi2SetReal", before | M_STEP_COMPLETE)) return fmi2Error;
    for (i = 0; i < nvr; i++) {
        if (vr[i] == VR_u) {
            inst->r[VR_u] = value[i];
            continue;
        }
        if (vr[i] >= N_REAL) return fail(inst, "fmi2SetReal: unknown value reference %u", (unsigned)vr[i]);
        if (!(inst->mode & before))
            return fail(inst, "fmi2SetReal: value reference %u is set before the initialization ends",
                        (unsigned)vr[i]);
        if (!isfinite(value[i]) || (vr[i] == VR_tau && !(value[i] > 0.0)))
            return fail(inst, "fmi2SetReal: value reference %u takes a finite value (tau a positive one), not %g",
                        (unsigned)vr[i], value[i]);
        inst->r[vr[i]] = value[i];
    }
    return fmi2OK;
}

fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Integer value[]) {
    (void)value;
    return nvr == 0 ? fmi2OK : fail((Instance *)c, "fmi2GetInteger: no Integer variable %u", (unsigned)vr[0]);
}

fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Integer value[]) {
    (void)value;
    return nvr == 0 ? fmi2OK : fail((Instance *)c, "fmi2SetInteger: no Integer variable %u", (unsigned)vr[0]);
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

/* ---- not provided: FMU state, directional derivatives, input interpolation ---- */

fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *FMUstate) {
    (void)FMUstate;
    return fail((Instance *)c, "fmi2GetFMUstate is not supported (canGetAndSetFMUstate is false)");
}

fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate FMUstate) {
    (void)FMUstate;
    return fail((Instance *)c, "fmi2SetFMUstate is not supported (canGetAndSetFMUstate is false)");
}

fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *FMUstate) {
    (void)FMUstate;
    return fail((Instance *)c, "fmi2FreeFMUstate is not supported (canGetAndSetFMUstate is false)");
}

fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate FMUstate, size_t *size) {
    (void)FMUstate;
    (void)size;
    return fail((Instance *)c, "fmi2SerializedFMUstateSize is not supported");
}

fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate FMUstate, fmi2Byte serializedState[],
                                 size_t size) {
    (void)FMUstate;
    (void)serializedState;
    (void)size;
    return fail((Instance *)c, "fmi2SerializeFMUstate is not supported");
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte serializedState[], size_t size,
                                   fmi2FMUstate *FMUstate) {
    (void)serializedState;
    (void)size;
    (void)FMUstate;
    return fail((Instance *)c, "fmi2DeSerializeFMUstate is not supported");
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
    return fail((Instance *)c, "fmi2GetDirectionalDerivative is not supported (providesDirectionalDerivative is "
                               "false)");
}

fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                       const fmi2Integer order[], const fmi2Real value[]) {
    (void)vr;
    (void)nvr;
    (void)order;
    (void)value;
    return fail((Instance *)c, "fmi2SetRealInputDerivatives: the FMU does not interpolate its inputs");
}

fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                        const fmi2Integer order[], fmi2Real value[]) {
    (void)vr;
    (void)nvr;
    (void)order;
    (void)value;
    return fail((Instance *)c, "fmi2GetRealOutputDerivatives: the FMU gives no output derivatives");
}

/* ---- co-simulation: the exact solution over the step ---- */

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real currentCommunicationPoint, fmi2Real communicationStepSize,
                      fmi2Boolean noSetFMUStatePriorToCurrentPoint) {
    Instance *inst = (Instance *)c;
    fmi2Real target;
    (void)noSetFMUStatePriorToCurrentPoint;
    if (!allowed(inst, "fmi2DoStep", M_STEP_COMPLETE)) return fmi2Error;
    if (!(communicationStepSize >= 0.0) || !isfinite(communicationStepSize))
        return fail(inst, "fmi2DoStep: the step size %g is not a finite non-negative number", communicationStepSize);
    target = inst->r[VR_K] * inst->r[VR_u];
    inst->r[VR_y] = target + (inst->r[VR_y] - target) * exp(-communicationStepSize / inst->r[VR_tau]);
    inst->time = currentCommunicationPoint + communicationStepSize;
    return fmi2OK;
}

fmi2Status fmi2CancelStep(fmi2Component c) {
    return fail((Instance *)c, "fmi2CancelStep: fmi2DoStep never returns fmi2Pending");
}

fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind s, fmi2Status *value) {
    (void)c;
    (void)s;
    (void)value;
    return fmi2Discard;
}

fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind s, fmi2Real *value) {
    Instance *inst = (Instance *)c;
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
