/* Test fixture: the linear single-track (bicycle) vehicle model as an FMI 3.0 FMU, model exchange and
   co-simulation (no scheduled execution, no event mode in co-simulation); the model, variable names, value
   references and units of single_track.c (FMI 2.0). tests/fmu_fixtures.py writes the model description and
   model.h and builds this file.

   States: yaw rate r [rad/s], side slip beta [rad] (both also outputs: one variable each).
   Inputs: steering_wheel_angle [rad], rear_wheel_angle [rad].
   Output: lateral_acceleration = v (dbeta/dt + r) [m/s2].

     delta_f = steering_wheel_angle / steering_ratio,   delta_r = rear_wheel_angle
     alpha_f = delta_f - beta - lf r / v,                alpha_r = delta_r - beta + lr r / v
     Fyf = cf alpha_f,  Fyr = cr alpha_r
     dbeta/dt = (Fyf + Fyr) / (m v) - r,                 dr/dt = (lf Fyf - lr Fyr) / Iz

   Every Float64 variable is addressed by its value reference (0 to 14, as in single_track.c); the independent
   variable time has VR_time (16), the Int32 n_sub VR_n_sub (15).

   Co-simulation: fmi3DoStep integrates with the classic Runge-Kutta method (order 4), n_sub equal substeps per
   communication step, the inputs held; it never returns early and never needs event handling. Directional
   derivatives (exact: the model is linear) of the derivatives and outputs with respect to the states and
   inputs; the FMU state (get, set, free) is a copy of all the instance's values and its time; no serialization.
   Every function of fmi3Functions.h is defined (importers such as fmpy bind them all); the ones this FMU does
   not support (scheduled execution, clocks, configuration mode, adjoint derivatives, variable dependencies,
   serialization, output derivatives, event mode in co-simulation) log an error and return fmi3Error (the
   instantiation of scheduled execution returns NULL). Only the fmi3* functions are exported.

   model.h (generated) defines FMU_GUID (the instantiation token), the value references VR_<name>, the start
   values START_<name> and the states' nominal values NOMINAL_<name>. */

#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi3Functions.h"
#include "model.h"

#define N_REAL 15 /* the Float64 variables but time: value references 0 to 14 */
#define N_STATES 2
#define N_SUB_MAX 1000000

enum { T_MODEL_EXCHANGE = 1, T_CO_SIMULATION = 2 };

enum { M_INSTANTIATED = 1, M_INITIALIZATION = 2, M_STEP = 4, M_EVENT = 8, M_CONTINUOUS = 16, M_TERMINATED = 32 };
#define M_RUNNING (M_STEP | M_EVENT | M_CONTINUOUS)
#define M_BEFORE (M_INSTANTIATED | M_INITIALIZATION)
#define M_ANY 63

typedef struct {
    fmi3Float64 time;
    fmi3Float64 r[N_REAL]; /* every Float64 variable but time, by value reference (derivatives, output current) */
    fmi3Int32 n_sub;
} Values;

typedef struct {
    fmi3InstanceEnvironment environment;
    fmi3LogMessageCallback log;
    char name[128];
    int type;
    int mode;
    Values s;
} Instance;

static void say(fmi3InstanceEnvironment environment, fmi3LogMessageCallback log, const char *name,
                const char *format, va_list args) {
    char message[512];
    int n;
    if (log == NULL) return;
    n = snprintf(message, sizeof message, "%s: ", name);
    if (n < 0 || (size_t)n >= sizeof message) n = 0;
    vsnprintf(message + n, sizeof message - (size_t)n, format, args);
    log(environment, fmi3Error, "logStatusError", message);
}

static fmi3Status fail(Instance *inst, const char *format, ...) {
    va_list args;
    if (inst == NULL) return fmi3Error;
    va_start(args, format);
    say(inst->environment, inst->log, inst->name, format, args);
    va_end(args);
    return fmi3Error;
}

/* An instantiation refused: the message through the callback, no instance. */
static fmi3Instance refuse(fmi3InstanceEnvironment environment, fmi3LogMessageCallback log, fmi3String name,
                           const char *format, ...) {
    va_list args;
    va_start(args, format);
    say(environment, log, name != NULL ? name : "", format, args);
    va_end(args);
    return NULL;
}

static int allowed(Instance *inst, const char *function, int modes) {
    if (inst == NULL) return 0;
    if (inst->mode & modes) return 1;
    fail(inst, "%s is not allowed in this state of the instance (mode %d)", function, inst->mode);
    return 0;
}

/* A model exchange function: the instance is one and in one of the modes. */
static int model_exchange(Instance *inst, const char *function, int modes) {
    if (inst == NULL) return 0;
    if (inst->type != T_MODEL_EXCHANGE) {
        fail(inst, "%s is a model exchange function; this instance is a co-simulation one", function);
        return 0;
    }
    return allowed(inst, function, modes);
}

static fmi3Status unsupported(fmi3Instance instance, const char *function, const char *why) {
    return fail((Instance *)instance, "%s: %s", function, why);
}

/* The derivatives and lateral_acceleration from the states, inputs and parameters in r. */
static void evaluate(fmi3Float64 *r) {
    const fmi3Float64 yaw = r[VR_yaw_rate], beta = r[VR_side_slip], v = r[VR_v];
    const fmi3Float64 delta_f = r[VR_steering_wheel_angle] / r[VR_steering_ratio], delta_r = r[VR_rear_wheel_angle];
    const fmi3Float64 fyf = r[VR_cf] * (delta_f - beta - r[VR_lf] * yaw / v);
    const fmi3Float64 fyr = r[VR_cr] * (delta_r - beta + r[VR_lr] * yaw / v);
    r[VR_der_side_slip] = (fyf + fyr) / (r[VR_m] * v) - yaw;
    r[VR_der_yaw_rate] = (r[VR_lf] * fyf - r[VR_lr] * fyr) / r[VR_Iz];
    r[VR_lateral_acceleration] = v * (r[VR_der_side_slip] + yaw);
}

/* dx/dt at the state x (yaw rate, side slip), the rest of r as it is. */
static void slope(fmi3Float64 *r, const fmi3Float64 x[N_STATES], fmi3Float64 dx[N_STATES]) {
    r[VR_yaw_rate] = x[0];
    r[VR_side_slip] = x[1];
    evaluate(r);
    dx[0] = r[VR_der_yaw_rate];
    dx[1] = r[VR_der_side_slip];
}

/* One RK4 step of h from the state in r; r holds the new state and its derivatives and outputs. */
static void rk4(fmi3Float64 *r, fmi3Float64 h) {
    fmi3Float64 x[N_STATES] = {r[VR_yaw_rate], r[VR_side_slip]}, y[N_STATES], k1[N_STATES], k2[N_STATES],
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
    fmi3Float64 *r = inst->s.r;
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

static int is_parameter(fmi3ValueReference vr) {
    return vr == VR_m || vr == VR_Iz || vr == VR_lf || vr == VR_lr || vr == VR_cf || vr == VR_cr || vr == VR_v ||
           vr == VR_steering_ratio;
}

static int is_state(fmi3ValueReference vr) { return vr == VR_yaw_rate || vr == VR_side_slip; }

/* nValues = nValueReferences: all the variables are scalars. */
static int scalars(Instance *inst, const char *function, size_t nValueReferences, size_t nValues) {
    if (nValues == nValueReferences) return 1;
    fail(inst, "%s: the variables are scalars: %lu values for %lu value references", function,
         (unsigned long)nValues, (unsigned long)nValueReferences);
    return 0;
}

static fmi3Instance create(fmi3String instanceName, fmi3String instantiationToken, int type,
                           fmi3InstanceEnvironment instanceEnvironment, fmi3LogMessageCallback logMessage) {
    Instance *inst;
    if (instantiationToken == NULL || strcmp(instantiationToken, FMU_GUID) != 0)
        return refuse(instanceEnvironment, logMessage, instanceName,
                      "the instantiation token %s is not this FMU's %s",
                      instantiationToken != NULL ? instantiationToken : "(none)", FMU_GUID);
    inst = (Instance *)calloc(1, sizeof(Instance));
    if (inst == NULL) return refuse(instanceEnvironment, logMessage, instanceName, "out of memory");
    inst->environment = instanceEnvironment;
    inst->log = logMessage;
    snprintf(inst->name, sizeof inst->name, "%s", instanceName != NULL ? instanceName : "");
    inst->type = type;
    restart(inst);
    return inst;
}

/* ---- common functions ---- */

const char *fmi3GetVersion(void) { return fmi3Version; }

fmi3Status fmi3SetDebugLogging(fmi3Instance instance, fmi3Boolean loggingOn, size_t nCategories,
                               const fmi3String categories[]) {
    (void)loggingOn;
    (void)nCategories;
    (void)categories;
    return allowed((Instance *)instance, "fmi3SetDebugLogging", M_ANY) ? fmi3OK : fmi3Error;
}

fmi3Instance fmi3InstantiateModelExchange(fmi3String instanceName, fmi3String instantiationToken,
                                          fmi3String resourcePath, fmi3Boolean visible, fmi3Boolean loggingOn,
                                          fmi3InstanceEnvironment instanceEnvironment,
                                          fmi3LogMessageCallback logMessage) {
    (void)resourcePath;
    (void)visible;
    (void)loggingOn;
    return create(instanceName, instantiationToken, T_MODEL_EXCHANGE, instanceEnvironment, logMessage);
}

fmi3Instance fmi3InstantiateCoSimulation(fmi3String instanceName, fmi3String instantiationToken,
                                         fmi3String resourcePath, fmi3Boolean visible, fmi3Boolean loggingOn,
                                         fmi3Boolean eventModeUsed, fmi3Boolean earlyReturnAllowed,
                                         const fmi3ValueReference requiredIntermediateVariables[],
                                         size_t nRequiredIntermediateVariables,
                                         fmi3InstanceEnvironment instanceEnvironment,
                                         fmi3LogMessageCallback logMessage,
                                         fmi3IntermediateUpdateCallback intermediateUpdate) {
    (void)resourcePath;
    (void)visible;
    (void)loggingOn;
    (void)earlyReturnAllowed; /* fmi3DoStep never returns early */
    (void)requiredIntermediateVariables;
    (void)intermediateUpdate; /* no intermediate updates */
    if (eventModeUsed)
        return refuse(instanceEnvironment, logMessage, instanceName,
                      "fmi3InstantiateCoSimulation: the FMU has no event mode (hasEventMode is false)");
    if (nRequiredIntermediateVariables != 0)
        return refuse(instanceEnvironment, logMessage, instanceName,
                      "fmi3InstantiateCoSimulation: the FMU provides no intermediate variables");
    return create(instanceName, instantiationToken, T_CO_SIMULATION, instanceEnvironment, logMessage);
}

fmi3Instance fmi3InstantiateScheduledExecution(fmi3String instanceName, fmi3String instantiationToken,
                                               fmi3String resourcePath, fmi3Boolean visible, fmi3Boolean loggingOn,
                                               fmi3InstanceEnvironment instanceEnvironment,
                                               fmi3LogMessageCallback logMessage, fmi3ClockUpdateCallback clockUpdate,
                                               fmi3LockPreemptionCallback lockPreemption,
                                               fmi3UnlockPreemptionCallback unlockPreemption) {
    (void)instantiationToken;
    (void)resourcePath;
    (void)visible;
    (void)loggingOn;
    (void)clockUpdate;
    (void)lockPreemption;
    (void)unlockPreemption;
    return refuse(instanceEnvironment, logMessage, instanceName,
                  "fmi3InstantiateScheduledExecution: the FMU offers model exchange and co-simulation only");
}

void fmi3FreeInstance(fmi3Instance instance) { free(instance); }

fmi3Status fmi3EnterInitializationMode(fmi3Instance instance, fmi3Boolean toleranceDefined, fmi3Float64 tolerance,
                                       fmi3Float64 startTime, fmi3Boolean stopTimeDefined, fmi3Float64 stopTime) {
    Instance *inst = (Instance *)instance;
    (void)toleranceDefined;
    (void)tolerance;
    (void)stopTimeDefined;
    (void)stopTime;
    if (!allowed(inst, "fmi3EnterInitializationMode", M_INSTANTIATED)) return fmi3Error;
    inst->s.time = startTime;
    inst->mode = M_INITIALIZATION;
    return fmi3OK;
}

fmi3Status fmi3ExitInitializationMode(fmi3Instance instance) {
    Instance *inst = (Instance *)instance;
    if (!allowed(inst, "fmi3ExitInitializationMode", M_INITIALIZATION)) return fmi3Error;
    evaluate(inst->s.r);
    /* model exchange: event mode; co-simulation without event mode: step mode */
    inst->mode = inst->type == T_CO_SIMULATION ? M_STEP : M_EVENT;
    return fmi3OK;
}

fmi3Status fmi3EnterEventMode(fmi3Instance instance) {
    Instance *inst = (Instance *)instance;
    if (inst != NULL && inst->type == T_CO_SIMULATION)
        return fail(inst, "fmi3EnterEventMode: the co-simulation FMU has no event mode (hasEventMode is false)");
    if (!allowed(inst, "fmi3EnterEventMode", M_CONTINUOUS)) return fmi3Error;
    inst->mode = M_EVENT;
    return fmi3OK;
}

fmi3Status fmi3Terminate(fmi3Instance instance) {
    Instance *inst = (Instance *)instance;
    if (!allowed(inst, "fmi3Terminate", M_RUNNING)) return fmi3Error;
    inst->mode = M_TERMINATED;
    return fmi3OK;
}

fmi3Status fmi3Reset(fmi3Instance instance) {
    Instance *inst = (Instance *)instance;
    if (!allowed(inst, "fmi3Reset", M_ANY)) return fmi3Error;
    restart(inst);
    return fmi3OK;
}

/* ---- getting and setting variable values: Float64 (all but n_sub) and Int32 (n_sub) ---- */

fmi3Status fmi3GetFloat64(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                          size_t nValueReferences, fmi3Float64 values[], size_t nValues) {
    Instance *inst = (Instance *)instance;
    size_t i;
    if (!allowed(inst, "fmi3GetFloat64", M_ANY)) return fmi3Error;
    if (!scalars(inst, "fmi3GetFloat64", nValueReferences, nValues)) return fmi3Error;
    evaluate(inst->s.r);
    for (i = 0; i < nValueReferences; i++) {
        const fmi3ValueReference ref = valueReferences[i];
        if (ref == VR_time)
            values[i] = inst->s.time;
        else if (ref < N_REAL)
            values[i] = inst->s.r[ref];
        else
            return fail(inst, "fmi3GetFloat64: value reference %u is no Float64 variable", (unsigned)ref);
    }
    return fmi3OK;
}

fmi3Status fmi3SetFloat64(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                          size_t nValueReferences, const fmi3Float64 values[], size_t nValues) {
    Instance *inst = (Instance *)instance;
    size_t i;
    if (!allowed(inst, "fmi3SetFloat64", M_BEFORE | M_RUNNING)) return fmi3Error;
    if (!scalars(inst, "fmi3SetFloat64", nValueReferences, nValues)) return fmi3Error;
    for (i = 0; i < nValueReferences; i++) {
        const fmi3ValueReference ref = valueReferences[i];
        if (ref == VR_steering_wheel_angle || ref == VR_rear_wheel_angle) {
            /* inputs: any time */
        } else if (is_state(ref)) {
            if (!(inst->mode & M_BEFORE))
                return fail(inst, "fmi3SetFloat64: the states are set before the initialization ends (model "
                                  "exchange: fmi3SetContinuousStates)");
        } else if (is_parameter(ref)) {
            if (!(inst->mode & (M_BEFORE | M_EVENT | M_STEP)))
                return fail(inst, "fmi3SetFloat64: a tunable parameter is set in event mode or step mode");
            if (!isfinite(values[i]) || ((ref == VR_m || ref == VR_Iz || ref == VR_v || ref == VR_steering_ratio) &&
                                         !(values[i] > 0.0)))
                return fail(inst, "fmi3SetFloat64: value reference %u takes a finite value (positive for m, Iz, v, "
                                  "steering_ratio), not %g", (unsigned)ref, values[i]);
        } else if (ref == VR_time) {
            return fail(inst, "fmi3SetFloat64: time is the independent variable (model exchange: fmi3SetTime)");
        } else {
            return fail(inst, "fmi3SetFloat64: value reference %u is no input, state or parameter", (unsigned)ref);
        }
        inst->s.r[ref] = values[i];
    }
    evaluate(inst->s.r);
    return fmi3OK;
}

fmi3Status fmi3GetInt32(fmi3Instance instance, const fmi3ValueReference valueReferences[], size_t nValueReferences,
                        fmi3Int32 values[], size_t nValues) {
    Instance *inst = (Instance *)instance;
    size_t i;
    if (!allowed(inst, "fmi3GetInt32", M_ANY)) return fmi3Error;
    if (!scalars(inst, "fmi3GetInt32", nValueReferences, nValues)) return fmi3Error;
    for (i = 0; i < nValueReferences; i++) {
        if (valueReferences[i] != VR_n_sub)
            return fail(inst, "fmi3GetInt32: value reference %u is no Int32 variable", (unsigned)valueReferences[i]);
        values[i] = inst->s.n_sub;
    }
    return fmi3OK;
}

fmi3Status fmi3SetInt32(fmi3Instance instance, const fmi3ValueReference valueReferences[], size_t nValueReferences,
                        const fmi3Int32 values[], size_t nValues) {
    Instance *inst = (Instance *)instance;
    size_t i;
    if (!allowed(inst, "fmi3SetInt32", M_BEFORE)) return fmi3Error;
    if (!scalars(inst, "fmi3SetInt32", nValueReferences, nValues)) return fmi3Error;
    for (i = 0; i < nValueReferences; i++) {
        if (valueReferences[i] != VR_n_sub)
            return fail(inst, "fmi3SetInt32: value reference %u is no Int32 variable", (unsigned)valueReferences[i]);
        if (values[i] < 1 || values[i] > N_SUB_MAX)
            return fail(inst, "fmi3SetInt32: n_sub is 1 to %d, not %d", N_SUB_MAX, (int)values[i]);
        inst->s.n_sub = values[i];
    }
    return fmi3OK;
}

/* The types without variables: nothing to get or set (no value references: fmi3OK, as FMI allows). */
#define NO_VARIABLES(NAME, TYPE, CONST)                                                                           \
    fmi3Status NAME(fmi3Instance instance, const fmi3ValueReference valueReferences[], size_t nValueReferences, \
                    CONST TYPE values[], size_t nValues) {                                                       \
        Instance *inst = (Instance *)instance;                                                                   \
        (void)values;                                                                                            \
        (void)nValues;                                                                                           \
        if (!allowed(inst, #NAME, M_ANY)) return fmi3Error;                                                      \
        if (nValueReferences == 0) return fmi3OK;                                                                \
        return fail(inst, "%s: value reference %u is no %s variable (the FMU has Float64 and Int32 ones)", #NAME, \
                    (unsigned)valueReferences[0], #TYPE);                                                        \
    }

NO_VARIABLES(fmi3GetFloat32, fmi3Float32, )
NO_VARIABLES(fmi3GetInt8, fmi3Int8, )
NO_VARIABLES(fmi3GetUInt8, fmi3UInt8, )
NO_VARIABLES(fmi3GetInt16, fmi3Int16, )
NO_VARIABLES(fmi3GetUInt16, fmi3UInt16, )
NO_VARIABLES(fmi3GetUInt32, fmi3UInt32, )
NO_VARIABLES(fmi3GetInt64, fmi3Int64, )
NO_VARIABLES(fmi3GetUInt64, fmi3UInt64, )
NO_VARIABLES(fmi3GetBoolean, fmi3Boolean, )
NO_VARIABLES(fmi3GetString, fmi3String, )
NO_VARIABLES(fmi3SetFloat32, fmi3Float32, const)
NO_VARIABLES(fmi3SetInt8, fmi3Int8, const)
NO_VARIABLES(fmi3SetUInt8, fmi3UInt8, const)
NO_VARIABLES(fmi3SetInt16, fmi3Int16, const)
NO_VARIABLES(fmi3SetUInt16, fmi3UInt16, const)
NO_VARIABLES(fmi3SetUInt32, fmi3UInt32, const)
NO_VARIABLES(fmi3SetInt64, fmi3Int64, const)
NO_VARIABLES(fmi3SetUInt64, fmi3UInt64, const)
NO_VARIABLES(fmi3SetBoolean, fmi3Boolean, const)
NO_VARIABLES(fmi3SetString, fmi3String, const)

fmi3Status fmi3GetBinary(fmi3Instance instance, const fmi3ValueReference valueReferences[], size_t nValueReferences,
                         size_t valueSizes[], fmi3Binary values[], size_t nValues) {
    Instance *inst = (Instance *)instance;
    (void)valueSizes;
    (void)values;
    (void)nValues;
    if (!allowed(inst, "fmi3GetBinary", M_ANY)) return fmi3Error;
    if (nValueReferences == 0) return fmi3OK;
    return fail(inst, "fmi3GetBinary: value reference %u is no Binary variable", (unsigned)valueReferences[0]);
}

fmi3Status fmi3SetBinary(fmi3Instance instance, const fmi3ValueReference valueReferences[], size_t nValueReferences,
                         const size_t valueSizes[], const fmi3Binary values[], size_t nValues) {
    Instance *inst = (Instance *)instance;
    (void)valueSizes;
    (void)values;
    (void)nValues;
    if (!allowed(inst, "fmi3SetBinary", M_ANY)) return fmi3Error;
    if (nValueReferences == 0) return fmi3OK;
    return fail(inst, "fmi3SetBinary: value reference %u is no Binary variable", (unsigned)valueReferences[0]);
}

fmi3Status fmi3GetClock(fmi3Instance instance, const fmi3ValueReference valueReferences[], size_t nValueReferences,
                        fmi3Clock values[]) {
    (void)valueReferences;
    (void)nValueReferences;
    (void)values;
    return unsupported(instance, "fmi3GetClock", "the FMU has no clocks");
}

fmi3Status fmi3SetClock(fmi3Instance instance, const fmi3ValueReference valueReferences[], size_t nValueReferences,
                        const fmi3Clock values[]) {
    (void)valueReferences;
    (void)nValueReferences;
    (void)values;
    return unsupported(instance, "fmi3SetClock", "the FMU has no clocks");
}

/* ---- variable dependencies: in the model description only (providesPerElementDependencies is false) ---- */

fmi3Status fmi3GetNumberOfVariableDependencies(fmi3Instance instance, fmi3ValueReference valueReference,
                                               size_t *nDependencies) {
    (void)valueReference;
    (void)nDependencies;
    return unsupported(instance, "fmi3GetNumberOfVariableDependencies",
                       "the dependencies are in modelDescription.xml only");
}

fmi3Status fmi3GetVariableDependencies(fmi3Instance instance, fmi3ValueReference dependent,
                                       size_t elementIndicesOfDependent[], fmi3ValueReference independents[],
                                       size_t elementIndicesOfIndependents[], fmi3DependencyKind dependencyKinds[],
                                       size_t nDependencies) {
    (void)dependent;
    (void)elementIndicesOfDependent;
    (void)independents;
    (void)elementIndicesOfIndependents;
    (void)dependencyKinds;
    (void)nDependencies;
    return unsupported(instance, "fmi3GetVariableDependencies", "the dependencies are in modelDescription.xml only");
}

/* ---- FMU state: a copy of the values and the time; no serialization ---- */

fmi3Status fmi3GetFMUState(fmi3Instance instance, fmi3FMUState *FMUState) {
    Instance *inst = (Instance *)instance;
    Values *copy;
    if (!allowed(inst, "fmi3GetFMUState", M_ANY)) return fmi3Error;
    if (FMUState == NULL) return fail(inst, "fmi3GetFMUState: no place for the FMU state");
    copy = (Values *)*FMUState;
    if (copy == NULL) {
        copy = (Values *)calloc(1, sizeof(Values));
        if (copy == NULL) return fail(inst, "fmi3GetFMUState: out of memory");
    }
    *copy = inst->s;
    *FMUState = copy;
    return fmi3OK;
}

fmi3Status fmi3SetFMUState(fmi3Instance instance, fmi3FMUState FMUState) {
    Instance *inst = (Instance *)instance;
    if (!allowed(inst, "fmi3SetFMUState", M_ANY)) return fmi3Error;
    if (FMUState == NULL) return fail(inst, "fmi3SetFMUState: no FMU state");
    inst->s = *(const Values *)FMUState;
    return fmi3OK;
}

fmi3Status fmi3FreeFMUState(fmi3Instance instance, fmi3FMUState *FMUState) {
    Instance *inst = (Instance *)instance;
    if (!allowed(inst, "fmi3FreeFMUState", M_ANY)) return fmi3Error;
    if (FMUState != NULL && *FMUState != NULL) {
        free(*FMUState);
        *FMUState = NULL;
    }
    return fmi3OK;
}

fmi3Status fmi3SerializedFMUStateSize(fmi3Instance instance, fmi3FMUState FMUState, size_t *size) {
    (void)FMUState;
    (void)size;
    return unsupported(instance, "fmi3SerializedFMUStateSize", "the FMU state is not serializable");
}

fmi3Status fmi3SerializeFMUState(fmi3Instance instance, fmi3FMUState FMUState, fmi3Byte serializedState[],
                                 size_t size) {
    (void)FMUState;
    (void)serializedState;
    (void)size;
    return unsupported(instance, "fmi3SerializeFMUState", "the FMU state is not serializable");
}

fmi3Status fmi3DeserializeFMUState(fmi3Instance instance, const fmi3Byte serializedState[], size_t size,
                                   fmi3FMUState *FMUState) {
    (void)serializedState;
    (void)size;
    (void)FMUState;
    return unsupported(instance, "fmi3DeserializeFMUState", "the FMU state is not serializable");
}

/* ---- directional derivatives: unknowns der(yaw_rate), der(side_slip), yaw_rate, side_slip,
        lateral_acceleration; knowns yaw_rate, side_slip, steering_wheel_angle, rear_wheel_angle ---- */

fmi3Status fmi3GetDirectionalDerivative(fmi3Instance instance, const fmi3ValueReference unknowns[],
                                        size_t nUnknowns, const fmi3ValueReference knowns[], size_t nKnowns,
                                        const fmi3Float64 seed[], size_t nSeed, fmi3Float64 sensitivity[],
                                        size_t nSensitivity) {
    Instance *inst = (Instance *)instance;
    const fmi3Float64 *r;
    fmi3Float64 d_yaw = 0.0, d_beta = 0.0, d_swa = 0.0, d_rwa = 0.0, d_fyf, d_fyr, d_der_beta;
    size_t i;
    if (!allowed(inst, "fmi3GetDirectionalDerivative", M_INITIALIZATION | M_RUNNING | M_TERMINATED))
        return fmi3Error;
    if (nSeed != nKnowns || nSensitivity != nUnknowns)
        return fail(inst, "fmi3GetDirectionalDerivative: the variables are scalars: one seed per known (%lu, not "
                          "%lu) and one sensitivity per unknown (%lu, not %lu)", (unsigned long)nKnowns,
                    (unsigned long)nSeed, (unsigned long)nUnknowns, (unsigned long)nSensitivity);
    r = inst->s.r;
    for (i = 0; i < nKnowns; i++) {
        switch (knowns[i]) {
        case VR_yaw_rate: d_yaw += seed[i]; break;
        case VR_side_slip: d_beta += seed[i]; break;
        case VR_steering_wheel_angle: d_swa += seed[i]; break;
        case VR_rear_wheel_angle: d_rwa += seed[i]; break;
        default:
            return fail(inst, "fmi3GetDirectionalDerivative: the knowns are the states and the inputs, not value "
                              "reference %u", (unsigned)knowns[i]);
        }
    }
    /* the partial derivatives of the linear model */
    d_fyf = r[VR_cf] * (d_swa / r[VR_steering_ratio] - d_beta - r[VR_lf] / r[VR_v] * d_yaw);
    d_fyr = r[VR_cr] * (d_rwa - d_beta + r[VR_lr] / r[VR_v] * d_yaw);
    d_der_beta = (d_fyf + d_fyr) / (r[VR_m] * r[VR_v]) - d_yaw;
    for (i = 0; i < nUnknowns; i++) {
        switch (unknowns[i]) {
        case VR_der_yaw_rate: sensitivity[i] = (r[VR_lf] * d_fyf - r[VR_lr] * d_fyr) / r[VR_Iz]; break;
        case VR_der_side_slip: sensitivity[i] = d_der_beta; break;
        case VR_yaw_rate: sensitivity[i] = d_yaw; break;
        case VR_side_slip: sensitivity[i] = d_beta; break;
        case VR_lateral_acceleration: sensitivity[i] = r[VR_v] * (d_der_beta + d_yaw); break;
        default:
            return fail(inst, "fmi3GetDirectionalDerivative: the unknowns are the derivatives and the outputs, not "
                              "value reference %u", (unsigned)unknowns[i]);
        }
    }
    return fmi3OK;
}

fmi3Status fmi3GetAdjointDerivative(fmi3Instance instance, const fmi3ValueReference unknowns[], size_t nUnknowns,
                                    const fmi3ValueReference knowns[], size_t nKnowns, const fmi3Float64 seed[],
                                    size_t nSeed, fmi3Float64 sensitivity[], size_t nSensitivity) {
    (void)unknowns;
    (void)nUnknowns;
    (void)knowns;
    (void)nKnowns;
    (void)seed;
    (void)nSeed;
    (void)sensitivity;
    (void)nSensitivity;
    return unsupported(instance, "fmi3GetAdjointDerivative",
                       "the FMU provides directional derivatives only (providesAdjointDerivatives is false)");
}

/* ---- configuration mode: no structural parameters ---- */

fmi3Status fmi3EnterConfigurationMode(fmi3Instance instance) {
    return unsupported(instance, "fmi3EnterConfigurationMode", "the FMU has no structural parameters");
}

fmi3Status fmi3ExitConfigurationMode(fmi3Instance instance) {
    return unsupported(instance, "fmi3ExitConfigurationMode", "the FMU has no structural parameters");
}

/* ---- clocks: none ---- */

fmi3Status fmi3GetIntervalDecimal(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                  size_t nValueReferences, fmi3Float64 intervals[],
                                  fmi3IntervalQualifier qualifiers[]) {
    (void)valueReferences;
    (void)nValueReferences;
    (void)intervals;
    (void)qualifiers;
    return unsupported(instance, "fmi3GetIntervalDecimal", "the FMU has no clocks");
}

fmi3Status fmi3GetIntervalFraction(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                   size_t nValueReferences, fmi3UInt64 counters[], fmi3UInt64 resolutions[],
                                   fmi3IntervalQualifier qualifiers[]) {
    (void)valueReferences;
    (void)nValueReferences;
    (void)counters;
    (void)resolutions;
    (void)qualifiers;
    return unsupported(instance, "fmi3GetIntervalFraction", "the FMU has no clocks");
}

fmi3Status fmi3GetShiftDecimal(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                               size_t nValueReferences, fmi3Float64 shifts[]) {
    (void)valueReferences;
    (void)nValueReferences;
    (void)shifts;
    return unsupported(instance, "fmi3GetShiftDecimal", "the FMU has no clocks");
}

fmi3Status fmi3GetShiftFraction(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                size_t nValueReferences, fmi3UInt64 counters[], fmi3UInt64 resolutions[]) {
    (void)valueReferences;
    (void)nValueReferences;
    (void)counters;
    (void)resolutions;
    return unsupported(instance, "fmi3GetShiftFraction", "the FMU has no clocks");
}

fmi3Status fmi3SetIntervalDecimal(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                  size_t nValueReferences, const fmi3Float64 intervals[]) {
    (void)valueReferences;
    (void)nValueReferences;
    (void)intervals;
    return unsupported(instance, "fmi3SetIntervalDecimal", "the FMU has no clocks");
}

fmi3Status fmi3SetIntervalFraction(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                   size_t nValueReferences, const fmi3UInt64 counters[],
                                   const fmi3UInt64 resolutions[]) {
    (void)valueReferences;
    (void)nValueReferences;
    (void)counters;
    (void)resolutions;
    return unsupported(instance, "fmi3SetIntervalFraction", "the FMU has no clocks");
}

fmi3Status fmi3SetShiftDecimal(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                               size_t nValueReferences, const fmi3Float64 shifts[]) {
    (void)valueReferences;
    (void)nValueReferences;
    (void)shifts;
    return unsupported(instance, "fmi3SetShiftDecimal", "the FMU has no clocks");
}

fmi3Status fmi3SetShiftFraction(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                size_t nValueReferences, const fmi3UInt64 counters[],
                                const fmi3UInt64 resolutions[]) {
    (void)valueReferences;
    (void)nValueReferences;
    (void)counters;
    (void)resolutions;
    return unsupported(instance, "fmi3SetShiftFraction", "the FMU has no clocks");
}

/* ---- discrete states: none (model exchange event mode) ---- */

fmi3Status fmi3EvaluateDiscreteStates(fmi3Instance instance) {
    return unsupported(instance, "fmi3EvaluateDiscreteStates",
                       "the FMU has no discrete states (providesEvaluateDiscreteStates is false)");
}

fmi3Status fmi3UpdateDiscreteStates(fmi3Instance instance, fmi3Boolean *discreteStatesNeedUpdate,
                                    fmi3Boolean *terminateSimulation, fmi3Boolean *nominalsOfContinuousStatesChanged,
                                    fmi3Boolean *valuesOfContinuousStatesChanged, fmi3Boolean *nextEventTimeDefined,
                                    fmi3Float64 *nextEventTime) {
    Instance *inst = (Instance *)instance;
    if (!allowed(inst, "fmi3UpdateDiscreteStates", M_EVENT)) return fmi3Error;
    if (discreteStatesNeedUpdate != NULL) *discreteStatesNeedUpdate = fmi3False;
    if (terminateSimulation != NULL) *terminateSimulation = fmi3False;
    if (nominalsOfContinuousStatesChanged != NULL) *nominalsOfContinuousStatesChanged = fmi3False;
    if (valuesOfContinuousStatesChanged != NULL) *valuesOfContinuousStatesChanged = fmi3False;
    if (nextEventTimeDefined != NULL) *nextEventTimeDefined = fmi3False;
    if (nextEventTime != NULL) *nextEventTime = 0.0;
    return fmi3OK;
}

/* ---- model exchange: no events ---- */

fmi3Status fmi3EnterContinuousTimeMode(fmi3Instance instance) {
    Instance *inst = (Instance *)instance;
    if (!model_exchange(inst, "fmi3EnterContinuousTimeMode", M_EVENT)) return fmi3Error;
    inst->mode = M_CONTINUOUS;
    return fmi3OK;
}

fmi3Status fmi3CompletedIntegratorStep(fmi3Instance instance, fmi3Boolean noSetFMUStatePriorToCurrentPoint,
                                       fmi3Boolean *enterEventMode, fmi3Boolean *terminateSimulation) {
    Instance *inst = (Instance *)instance;
    (void)noSetFMUStatePriorToCurrentPoint;
    if (!model_exchange(inst, "fmi3CompletedIntegratorStep", M_CONTINUOUS)) return fmi3Error;
    if (enterEventMode != NULL) *enterEventMode = fmi3False;
    if (terminateSimulation != NULL) *terminateSimulation = fmi3False;
    return fmi3OK;
}

fmi3Status fmi3SetTime(fmi3Instance instance, fmi3Float64 time) {
    Instance *inst = (Instance *)instance;
    if (!model_exchange(inst, "fmi3SetTime", M_EVENT | M_CONTINUOUS)) return fmi3Error;
    inst->s.time = time;
    return fmi3OK;
}

fmi3Status fmi3SetContinuousStates(fmi3Instance instance, const fmi3Float64 continuousStates[],
                                   size_t nContinuousStates) {
    Instance *inst = (Instance *)instance;
    if (!model_exchange(inst, "fmi3SetContinuousStates", M_CONTINUOUS)) return fmi3Error;
    if (nContinuousStates != N_STATES)
        return fail(inst, "fmi3SetContinuousStates: %d states, not %lu", N_STATES, (unsigned long)nContinuousStates);
    inst->s.r[VR_yaw_rate] = continuousStates[0];
    inst->s.r[VR_side_slip] = continuousStates[1];
    evaluate(inst->s.r);
    return fmi3OK;
}

#define M_EVALUATE (M_INITIALIZATION | M_EVENT | M_CONTINUOUS | M_TERMINATED)

fmi3Status fmi3GetContinuousStateDerivatives(fmi3Instance instance, fmi3Float64 derivatives[],
                                             size_t nContinuousStates) {
    Instance *inst = (Instance *)instance;
    if (!model_exchange(inst, "fmi3GetContinuousStateDerivatives", M_EVALUATE)) return fmi3Error;
    if (nContinuousStates != N_STATES)
        return fail(inst, "fmi3GetContinuousStateDerivatives: %d states, not %lu", N_STATES,
                    (unsigned long)nContinuousStates);
    evaluate(inst->s.r);
    derivatives[0] = inst->s.r[VR_der_yaw_rate];
    derivatives[1] = inst->s.r[VR_der_side_slip];
    return fmi3OK;
}

fmi3Status fmi3GetEventIndicators(fmi3Instance instance, fmi3Float64 eventIndicators[], size_t nEventIndicators) {
    Instance *inst = (Instance *)instance;
    (void)eventIndicators;
    if (!model_exchange(inst, "fmi3GetEventIndicators", M_EVALUATE)) return fmi3Error;
    return nEventIndicators == 0 ? fmi3OK : fail(inst, "fmi3GetEventIndicators: the FMU has no event indicators");
}

fmi3Status fmi3GetContinuousStates(fmi3Instance instance, fmi3Float64 continuousStates[], size_t nContinuousStates) {
    Instance *inst = (Instance *)instance;
    if (!model_exchange(inst, "fmi3GetContinuousStates", M_EVALUATE)) return fmi3Error;
    if (nContinuousStates != N_STATES)
        return fail(inst, "fmi3GetContinuousStates: %d states, not %lu", N_STATES, (unsigned long)nContinuousStates);
    continuousStates[0] = inst->s.r[VR_yaw_rate];
    continuousStates[1] = inst->s.r[VR_side_slip];
    return fmi3OK;
}

fmi3Status fmi3GetNominalsOfContinuousStates(fmi3Instance instance, fmi3Float64 nominals[],
                                             size_t nContinuousStates) {
    Instance *inst = (Instance *)instance;
    if (!model_exchange(inst, "fmi3GetNominalsOfContinuousStates", M_EVALUATE)) return fmi3Error;
    if (nContinuousStates != N_STATES)
        return fail(inst, "fmi3GetNominalsOfContinuousStates: %d states, not %lu", N_STATES,
                    (unsigned long)nContinuousStates);
    nominals[0] = NOMINAL_yaw_rate; /* a tool's absolute tolerance is often the nominal times the relative one */
    nominals[1] = NOMINAL_side_slip;
    return fmi3OK;
}

fmi3Status fmi3GetNumberOfEventIndicators(fmi3Instance instance, size_t *nEventIndicators) {
    Instance *inst = (Instance *)instance;
    if (!allowed(inst, "fmi3GetNumberOfEventIndicators", M_ANY)) return fmi3Error;
    if (nEventIndicators == NULL) return fail(inst, "fmi3GetNumberOfEventIndicators: no place for the number");
    *nEventIndicators = 0;
    return fmi3OK;
}

fmi3Status fmi3GetNumberOfContinuousStates(fmi3Instance instance, size_t *nContinuousStates) {
    Instance *inst = (Instance *)instance;
    if (!allowed(inst, "fmi3GetNumberOfContinuousStates", M_ANY)) return fmi3Error;
    if (nContinuousStates == NULL) return fail(inst, "fmi3GetNumberOfContinuousStates: no place for the number");
    *nContinuousStates = N_STATES;
    return fmi3OK;
}

/* ---- co-simulation: RK4, n_sub substeps per communication step, the inputs held; no event mode ---- */

fmi3Status fmi3EnterStepMode(fmi3Instance instance) {
    return unsupported(instance, "fmi3EnterStepMode",
                       "the FMU has no event mode in co-simulation (hasEventMode is false): fmi3ExitInitializationMode "
                       "enters step mode");
}

fmi3Status fmi3GetOutputDerivatives(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                    size_t nValueReferences, const fmi3Int32 orders[], fmi3Float64 values[],
                                    size_t nValues) {
    (void)valueReferences;
    (void)nValueReferences;
    (void)orders;
    (void)values;
    (void)nValues;
    return unsupported(instance, "fmi3GetOutputDerivatives",
                       "the FMU gives no output derivatives (maxOutputDerivativeOrder is 0)");
}

fmi3Status fmi3DoStep(fmi3Instance instance, fmi3Float64 currentCommunicationPoint,
                      fmi3Float64 communicationStepSize, fmi3Boolean noSetFMUStatePriorToCurrentPoint,
                      fmi3Boolean *eventHandlingNeeded, fmi3Boolean *terminateSimulation, fmi3Boolean *earlyReturn,
                      fmi3Float64 *lastSuccessfulTime) {
    Instance *inst = (Instance *)instance;
    fmi3Float64 h;
    fmi3Int32 k;
    (void)noSetFMUStatePriorToCurrentPoint;
    if (!allowed(inst, "fmi3DoStep", M_STEP)) return fmi3Error;
    if (!(communicationStepSize >= 0.0) || !isfinite(communicationStepSize))
        return fail(inst, "fmi3DoStep: the step size %g is not a finite non-negative number", communicationStepSize);
    h = communicationStepSize / (fmi3Float64)inst->s.n_sub;
    if (communicationStepSize > 0.0)
        for (k = 0; k < inst->s.n_sub; k++) rk4(inst->s.r, h);
    inst->s.time = currentCommunicationPoint + communicationStepSize;
    if (eventHandlingNeeded != NULL) *eventHandlingNeeded = fmi3False;
    if (terminateSimulation != NULL) *terminateSimulation = fmi3False;
    if (earlyReturn != NULL) *earlyReturn = fmi3False;
    if (lastSuccessfulTime != NULL) *lastSuccessfulTime = inst->s.time;
    return fmi3OK;
}

/* ---- scheduled execution: not offered ---- */

fmi3Status fmi3ActivateModelPartition(fmi3Instance instance, fmi3ValueReference clockReference,
                                      fmi3Float64 activationTime) {
    (void)clockReference;
    (void)activationTime;
    return unsupported(instance, "fmi3ActivateModelPartition", "the FMU offers no scheduled execution");
}
