/* Test fixture: the linear single-track (bicycle) vehicle model as an FMI 2.0 FMU, model exchange and
   co-simulation (tests/fmu_fixtures.py writes the model description and model.h and builds this file).

   States: yaw rate r [rad/s], side slip beta [rad] (both also outputs: one variable each).
   Inputs: steering_wheel_angle [rad], rear_wheel_angle [rad].
   Output: lateral_acceleration = v (dbeta/dt + r) [m/s2].

     delta_f = steering_wheel_angle / steering_ratio,   delta_r = rear_wheel_angle
     alpha_f = delta_f - beta - lf r / v,                alpha_r = delta_r - beta + lr r / v
     Fyf = cf alpha_f,  Fyr = cr alpha_r
     dbeta/dt = (Fyf + Fyr) / (m v) - r,                 dr/dt = (lf Fyf - lr Fyr) / Iz

   Co-simulation: fmi2DoStep integrates with the classic Runge-Kutta method (order 4), n_sub equal substeps per
   communication step, the inputs held. Directional derivatives (exact: the model is linear) of the
   derivatives and outputs with respect to the states and inputs; the FMU state (get, set, free) is a copy of
   all the instance's values and its time; no serialization.

   model.h (generated) defines FMU_GUID, the value references VR_<name>, the start values START_<name> and the
   states' nominal values NOMINAL_<name>. */

#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <string.h>

#include "fmi2Functions.h"
#include "model.h"

#define N_REAL 15
#define N_STATES 2
#define N_SUB_MAX 1000000

enum { M_INSTANTIATED = 1, M_INITIALIZATION = 2, M_STEP_COMPLETE = 4, M_EVENT = 8, M_CONTINUOUS = 16,
       M_TERMINATED = 32 };
#define M_RUNNING (M_STEP_COMPLETE | M_EVENT | M_CONTINUOUS)
#define M_ANY 63

typedef struct {
    fmi2Real time;
    fmi2Real r[N_REAL]; /* every Real variable, by value reference (derivatives and outputs kept current) */
    fmi2Integer n_sub;
} Values;

typedef struct {
    fmi2CallbackFunctions cb;
    char name[128];
    fmi2Type type;
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

/* The derivatives and lateral_acceleration from the states, inputs and parameters in r. */
static void evaluate(fmi2Real *r) {
    const fmi2Real yaw = r[VR_yaw_rate], beta = r[VR_side_slip], v = r[VR_v];
    const fmi2Real delta_f = r[VR_steering_wheel_angle] / r[VR_steering_ratio], delta_r = r[VR_rear_wheel_angle];
    const fmi2Real fyf = r[VR_cf] * (delta_f - beta - r[VR_lf] * yaw / v);
    const fmi2Real fyr = r[VR_cr] * (delta_r - beta + r[VR_lr] * yaw / v);
    r[VR_der_side_slip] = (fyf + fyr) / (r[VR_m] * v) - yaw;
    r[VR_der_yaw_rate] = (r[VR_lf] * fyf - r[VR_lr] * fyr) / r[VR_Iz];
    r[VR_lateral_acceleration] = v * (r[VR_der_side_slip] + yaw);
}

/* dx/dt at the state x (yaw rate, side slip), the rest of r as it is. */
static void slope(fmi2Real *r, const fmi2Real x[N_STATES], fmi2Real dx[N_STATES]) {
    r[VR_yaw_rate] = x[0];
    r[VR_side_slip] = x[1];
    evaluate(r);
    dx[0] = r[VR_der_yaw_rate];
    dx[1] = r[VR_der_side_slip];
}

/* One RK4 step of h from the state in r; r holds the new state and its derivatives and outputs. */
static void rk4(fmi2Real *r, fmi2Real h) {
    fmi2Real x[N_STATES] = {r[VR_yaw_rate], r[VR_side_slip]}, y[N_STATES], k1[N_STATES], k2[N_STATES],
             k3[N_STATES], k4[N_STATES];
    int i;
    slope(r, x, k1);
    for (i = 0; i < N_STATES; i++) y[i] = x[i] + 0.5 * h * k1[i];
    slope(r, y, k2);
    for (i = 0; i < N_STATES; i++) y[i] = x[i] + 0.5 * h * k2[i];
    slope(r, y, k3);
    for (i = 0; i < N_STATES; i++) y[i] = x[i] + h * k3[i];
    slope(r, y, k4);
    for (i = 0; i < N_STATES; i++) x[i] += h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]);
    r[VR_yaw_rate] = x[0];
    r[VR_side_slip] = x[1];
    evaluate(r);
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
    inst->s.n_sub = START_n_sub;
    evaluate(r);
    inst->mode = M_INSTANTIATED;
}

static int is_parameter(fmi2ValueReference vr) {
    return vr == VR_m || vr == VR_Iz || vr == VR_lf || vr == VR_lr || vr == VR_cf || vr == VR_cr || vr == VR_v ||
           vr == VR_steering_ratio;
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
    (void)fmuResourceLocation;
    (void)visible;
    (void)loggingOn;
    if (functions == NULL || functions->allocateMemory == NULL || functions->freeMemory == NULL) return NULL;
    if (fmuGUID == NULL || strcmp(fmuGUID, FMU_GUID) != 0) return NULL;
    if (fmuType != fmi2ModelExchange && fmuType != fmi2CoSimulation) return NULL;
    inst = (Instance *)functions->allocateMemory(1, sizeof(Instance));
    if (inst == NULL) return NULL;
    inst->cb = *functions;
    snprintf(inst->name, sizeof inst->name, "%s", instanceName != NULL ? instanceName : "");
    inst->type = fmuType;
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
    inst->mode = inst->type == fmi2CoSimulation ? M_STEP_COMPLETE : M_EVENT;
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
        if (vr[i] >= N_REAL) return fail(inst, "fmi2GetReal: unknown value reference %u", (unsigned)vr[i]);
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
            if (!(inst->mode & (before | M_EVENT | M_STEP_COMPLETE)))
                return fail(inst, "fmi2SetReal: a tunable parameter is set in event mode or between steps");
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
        if (value[i] < 1 || value[i] > N_SUB_MAX)
            return fail(inst, "fmi2SetInteger: n_sub is 1 to %d, not %d", N_SUB_MAX, (int)value[i]);
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

/* ---- FMU state: a copy of the values and the time; no serialization ---- */

fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *FMUstate) {
    Instance *inst = (Instance *)c;
    Values *copy;
    if (!allowed(inst, "fmi2GetFMUstate", M_ANY) || FMUstate == NULL) return fmi2Error;
    copy = (Values *)*FMUstate;
    if (copy == NULL) {
        copy = (Values *)inst->cb.allocateMemory(1, sizeof(Values));
        if (copy == NULL) return fail(inst, "fmi2GetFMUstate: out of memory");
    }
    *copy = inst->s;
    *FMUstate = copy;
    return fmi2OK;
}

fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate FMUstate) {
    Instance *inst = (Instance *)c;
    if (!allowed(inst, "fmi2SetFMUstate", M_ANY)) return fmi2Error;
    if (FMUstate == NULL) return fail(inst, "fmi2SetFMUstate: no FMU state");
    inst->s = *(const Values *)FMUstate;
    return fmi2OK;
}

fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *FMUstate) {
    Instance *inst = (Instance *)c;
    if (!allowed(inst, "fmi2FreeFMUstate", M_ANY)) return fmi2Error;
    if (FMUstate != NULL && *FMUstate != NULL) {
        inst->cb.freeMemory(*FMUstate);
        *FMUstate = NULL;
    }
    return fmi2OK;
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

/* ---- directional derivatives: unknowns der(yaw_rate), der(side_slip), yaw_rate, side_slip,
        lateral_acceleration; knowns yaw_rate, side_slip, steering_wheel_angle, rear_wheel_angle ---- */

fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference vUnknown_ref[], size_t nUnknown,
                                        const fmi2ValueReference vKnown_ref[], size_t nKnown,
                                        const fmi2Real dvKnown[], fmi2Real dvUnknown[]) {
    Instance *inst = (Instance *)c;
    const fmi2Real *r;
    fmi2Real d_yaw = 0.0, d_beta = 0.0, d_swa = 0.0, d_rwa = 0.0, d_fyf, d_fyr, d_der_beta;
    size_t i;
    if (!allowed(inst, "fmi2GetDirectionalDerivative", M_INITIALIZATION | M_RUNNING)) return fmi2Error;
    r = inst->s.r;
    for (i = 0; i < nKnown; i++) {
        switch (vKnown_ref[i]) {
        case VR_yaw_rate: d_yaw += dvKnown[i]; break;
        case VR_side_slip: d_beta += dvKnown[i]; break;
        case VR_steering_wheel_angle: d_swa += dvKnown[i]; break;
        case VR_rear_wheel_angle: d_rwa += dvKnown[i]; break;
        default:
            return fail(inst, "fmi2GetDirectionalDerivative: the knowns are the states and the inputs, not value "
                              "reference %u", (unsigned)vKnown_ref[i]);
        }
    }
    /* the partial derivatives of the linear model */
    d_fyf = r[VR_cf] * (d_swa / r[VR_steering_ratio] - d_beta - r[VR_lf] / r[VR_v] * d_yaw);
    d_fyr = r[VR_cr] * (d_rwa - d_beta + r[VR_lr] / r[VR_v] * d_yaw);
    d_der_beta = (d_fyf + d_fyr) / (r[VR_m] * r[VR_v]) - d_yaw;
    for (i = 0; i < nUnknown; i++) {
        switch (vUnknown_ref[i]) {
        case VR_der_yaw_rate: dvUnknown[i] = (r[VR_lf] * d_fyf - r[VR_lr] * d_fyr) / r[VR_Iz]; break;
        case VR_der_side_slip: dvUnknown[i] = d_der_beta; break;
        case VR_yaw_rate: dvUnknown[i] = d_yaw; break;
        case VR_side_slip: dvUnknown[i] = d_beta; break;
        case VR_lateral_acceleration: dvUnknown[i] = r[VR_v] * (d_der_beta + d_yaw); break;
        default:
            return fail(inst, "fmi2GetDirectionalDerivative: the unknowns are the derivatives and the outputs, not "
                              "value reference %u", (unsigned)vUnknown_ref[i]);
        }
    }
    return fmi2OK;
}

/* ---- model exchange: no events ---- */

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
    (void)noSetFMUStatePriorToCurrentPoint;
    if (!allowed(inst, "fmi2CompletedIntegratorStep", M_CONTINUOUS)) return fmi2Error;
    *enterEventMode = fmi2False;
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
    x_nominal[0] = NOMINAL_yaw_rate; /* a tool's absolute tolerance is often the nominal times the relative one */
    x_nominal[1] = NOMINAL_side_slip;
    return fmi2OK;
}

fmi2Status fmi2GetEventIndicators(fmi2Component c, fmi2Real eventIndicators[], size_t ni) {
    Instance *inst = (Instance *)c;
    (void)eventIndicators;
    if (!allowed(inst, "fmi2GetEventIndicators", M_ANY)) return fmi2Error;
    return ni == 0 ? fmi2OK : fail(inst, "fmi2GetEventIndicators: the FMU has no event indicators");
}

/* ---- co-simulation: RK4, n_sub substeps per communication step, the inputs held ---- */

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

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real currentCommunicationPoint, fmi2Real communicationStepSize,
                      fmi2Boolean noSetFMUStatePriorToCurrentPoint) {
    Instance *inst = (Instance *)c;
    fmi2Real h;
    fmi2Integer k;
    (void)noSetFMUStatePriorToCurrentPoint;
    if (!allowed(inst, "fmi2DoStep", M_STEP_COMPLETE)) return fmi2Error;
    if (!(communicationStepSize >= 0.0) || !isfinite(communicationStepSize))
        return fail(inst, "fmi2DoStep: the step size %g is not a finite non-negative number", communicationStepSize);
    h = communicationStepSize / (fmi2Real)inst->s.n_sub;
    if (communicationStepSize > 0.0)
        for (k = 0; k < inst->s.n_sub; k++) rk4(inst->s.r, h);
    inst->s.time = currentCommunicationPoint + communicationStepSize;
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
    *value = inst->s.time;
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
