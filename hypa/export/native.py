"""The C step as a source-code FMI 2.0 FMU, co-simulation and model exchange, with its binary for this machine.

The step's C99 source (``step.c``: ``hypa_step`` and ``HYPA_STATE_SIZE``, ``HYPA_INPUT_SIZE``,
``HYPA_OUTPUT_SIZE``) travels in the FMU with a hand-written FMI 2.0 wrapper (``FMU_C``, ``sources/fmu.c``,
which includes ``step.c`` and the generated ``model.h``: one compilation unit), the FMI 2.0 headers (from
fmpy) and a build description; ``binaries/<platform>/`` holds the library the machine's C compiler built
from them, which needs nothing but libc and libm. The variables are today's pythonfmu FMU's
(``hypa.export.fmu``): the inputs and scheduling signals, the outputs (direct feedthrough), the fixed
parameters ``initial_state[i]`` and the read-only calculated parameters ``parameter.<name>``, SI with units.

The step is a discrete-time system on the grid t_k = startTime + k dt:

* co-simulation: ``fmi2DoStep(t, h)`` advances h / dt samples (h a whole multiple of dt), inputs held;
  fmpy steps it with ``hypa.export.fmu.run_fmu``;
* model exchange: no continuous states; the event iteration at t_k (``fmi2NewDiscreteStates``) latches
  state[k+1] from state[k] and the inputs at t_k, the one at t_{k+1} makes it the state (sample and hold),
  each asks for the next time event; over [t_k, t_{k+1}) the state is state[k] and the outputs follow the
  inputs, as in co-simulation between communication points; :func:`run_native_me` steps it.

``compile_check`` compiles the sources again with the warnings as errors, ``validate`` runs fmpy's
validation, ``time_c_step`` times the bare C step.
"""

from __future__ import annotations

import platform
import re
import shutil
import subprocess
import tempfile
import time
import uuid
import zipfile
from datetime import datetime, timezone
from pathlib import Path
from typing import TYPE_CHECKING
from xml.etree import ElementTree

import numpy as np

from hypa.export.blocks import ExportError

if TYPE_CHECKING:
    from hypa.export.blocks import StateSlot
    from hypa.export.reference import Reference

PLATFORMS = {("Linux", "x86_64"): "linux64", ("Linux", "amd64"): "linux64", ("Darwin", "x86_64"): "darwin64",
             ("Darwin", "arm64"): "darwin64", ("Windows", "amd64"): "win64", ("Windows", "x86_64"): "win64"}
SUFFIXES = {"linux64": ".so", "darwin64": ".dylib", "win64": ".dll"}
HEADERS = ("fmi2Functions.h", "fmi2FunctionTypes.h", "fmi2TypesPlatform.h")
LIBRARY_FLAGS = ("-shared", "-fPIC", "-O2", "-std=c99", "-fvisibility=hidden")
# compile_check: the strictest set of warnings the sources compile without (as errors), tried in this order
WARNING_LEVELS = (("-Wall", "-Wextra", "-Wpedantic"), ("-Wall",))
SIZES = ("HYPA_STATE_SIZE", "HYPA_INPUT_SIZE", "HYPA_OUTPUT_SIZE")
PARAMETER_TEXT = "fitted value, read-only: the step has it baked in"

FMU_C = r"""/* The FMI 2.0 interface of hypa's exported step, co-simulation and model exchange (hypa.export.native).

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
"""

BENCH_C = r"""/* hypa's C step, timed (hypa.export.native.time_c_step): bench DATA prints the nanoseconds per step, the
   steps timed and a checksum of the outputs. DATA: the row count (int64), the initial state (r doubles), the
   input rows (rows x m doubles). The rows run in turn from the initial state, again from the first when all
   have run; the steps double from 16 until a run takes BENCH_SECONDS or BENCH_MAX_STEPS steps. */
#define _POSIX_C_SOURCE 199309L
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "step.c"

#define BENCH_BUFFER(n) ((n) > 0 ? (n) : 1)
#define BENCH_SECONDS 0.2
#define BENCH_MAX_STEPS 1000000L

static double bench_now(void) {
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return (double)t.tv_sec + 1e-9 * (double)t.tv_nsec;
}

static double bench_run(const double *x0, const double *u, long rows, long steps, double *checksum) {
    double a[BENCH_BUFFER(HYPA_STATE_SIZE)], b[BENCH_BUFFER(HYPA_STATE_SIZE)], y[BENCH_BUFFER(HYPA_OUTPUT_SIZE)];
    double *state = a, *next = b, *swap, started;
    long k, row = 0;
    int j;
    memcpy(a, x0, sizeof a);
    started = bench_now();
    for (k = 0; k < steps; k++) {
        hypa_step(state, u + row * HYPA_INPUT_SIZE, next, y);
        for (j = 0; j < HYPA_OUTPUT_SIZE; j++) *checksum += y[j];
        swap = state;
        state = next;
        next = swap;
        if (++row == rows) {
            row = 0;
            memcpy(state, x0, sizeof a);
        }
    }
    return bench_now() - started;
}

int main(int argc, char **argv) {
    FILE *file;
    int64_t rows;
    size_t values;
    double *x0, *u, seconds, checksum = 0.0;
    long steps = 16;
    if (argc != 2 || (file = fopen(argv[1], "rb")) == NULL) {
        fprintf(stderr, "usage: bench DATA\n");
        return 2;
    }
    if (fread(&rows, sizeof rows, 1, file) != 1 || rows < 1) {
        fprintf(stderr, "bench: no rows in %s\n", argv[1]);
        return 2;
    }
    values = (size_t)rows * (size_t)HYPA_INPUT_SIZE;
    x0 = (double *)calloc(BENCH_BUFFER(HYPA_STATE_SIZE), sizeof *x0);
    u = (double *)calloc(values > 0 ? values : 1, sizeof *u);
    if (x0 == NULL || u == NULL || fread(x0, sizeof *x0, (size_t)HYPA_STATE_SIZE, file) != (size_t)HYPA_STATE_SIZE
        || fread(u, sizeof *u, values, file) != values) {
        fprintf(stderr, "bench: %s is short\n", argv[1]);
        return 2;
    }
    fclose(file);
    for (;;) {
        seconds = bench_run(x0, u, (long)rows, steps, &checksum);
        if (seconds >= BENCH_SECONDS || steps >= BENCH_MAX_STEPS) break;
        steps = 2 * steps < BENCH_MAX_STEPS ? 2 * steps : BENCH_MAX_STEPS;
    }
    printf("%.9g %ld %.17g\n", 1e9 * seconds / (double)steps, steps, checksum);
    free(x0);
    free(u);
    return 0;
}
"""


def c_identifier(name: str) -> str:
    """An FMU model identifier from a model's name: an ASCII C identifier, "hypa_" and the name with every
    character outside [A-Za-z0-9_] replaced by "_"."""
    return "hypa_" + re.sub(r"[^A-Za-z0-9_]", "_", name)


def platform_folder() -> str:
    """The FMI 2.0 binaries folder of this machine (linux64, darwin64, win64); ``ExportError`` on others."""
    key = (platform.system(), platform.machine().lower())
    if key not in PLATFORMS:
        raise ExportError(f"format=fmu (native): no FMI 2.0 platform for {key[0]} on {key[1]} "
                          "(linux64, darwin64 and win64 are)")
    return PLATFORMS[key]


def c_compiler() -> str:
    """The machine's C compiler (cc, gcc or clang from PATH); ``ExportError`` when there is none."""
    found = shutil.which("cc") or shutil.which("gcc") or shutil.which("clang")
    if found is None:
        raise ExportError("format=fmu (native) needs a C compiler: none of cc, gcc, clang is on PATH")
    return found


def step_sizes(step_c: str) -> tuple[int, int, int]:
    """(r, m + q, p): the state, input and output sizes the step source defines."""
    sizes = []
    for name in SIZES:
        found = re.search(rf"^\s*#\s*define\s+{name}\s+\(?\s*(\d+)\s*\)?", step_c, re.MULTILINE)
        if found is None:
            raise ExportError(f"the C step source defines no {name}")
        sizes.append(int(found.group(1)))
    return sizes[0], sizes[1], sizes[2]


def build_native_fmu(step_c: str, path: Path, description: dict, reference: Reference, slots: list[StateSlot],
                     parameters: dict[str, tuple[float, str]]) -> Path:
    """Write the source-code FMU of the C step ``step_c`` to ``path``, its binary built for this machine;
    ``description``: ``export.json``'s contents ("model", "dt", "inputs", "outputs": names and units)."""
    folder, cc = platform_folder(), c_compiler()
    _check_step(step_c, description, reference, slots, parameters)
    name = c_identifier(description["model"])
    guid = "{" + str(uuid.uuid4()) + "}"
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        sources = root / "sources"
        sources.mkdir()
        _write_sources(sources, step_c, description, reference, parameters, guid)
        (root / "modelDescription.xml").write_bytes(
            _model_description(name, guid, description, reference, slots, parameters))
        (root / "documentation").mkdir()
        (root / "documentation" / "build.txt").write_text(_build_text(name), encoding="utf-8")
        library = root / "binaries" / folder / f"{name}{SUFFIXES[folder]}"
        library.parent.mkdir(parents=True)
        extra = ["-Wl,-z,defs"] if folder == "linux64" else []
        _compile([cc, *LIBRARY_FLAGS, *extra, "-o", str(library), "fmu.c", "-lm"], sources, "build the FMU's binary")
        _zip(root, Path(path))
    return Path(path)


def _check_step(step_c: str, description: dict, reference: Reference, slots: list[StateSlot],
                 parameters: dict[str, tuple[float, str]]) -> None:
    """``ExportError`` unless the step source's sizes are the export's and the reference's, and the values the
    FMU holds are finite."""
    r, m, p = step_sizes(step_c)
    inputs = [s["name"] for s in description["inputs"]]
    outputs = [s["name"] for s in description["outputs"]]
    if (r, m, p) != (len(reference.initial_state), len(inputs), len(outputs)) or len(slots) != r:
        raise ExportError(f"the C step's sizes (state {r}, inputs {m}, outputs {p}) are not the export's (state "
                          f"{len(reference.initial_state)}, inputs {len(inputs)}, outputs {len(outputs)})")
    if tuple(inputs) != tuple(reference.input_names) or tuple(outputs) != tuple(reference.output_names):
        raise ExportError("export.json's inputs and outputs are not the reference's, in name or order")
    values = [*reference.initial_state, *reference.u[reference.first], *(v for v, _ in parameters.values())]
    if not np.isfinite(values).all() or not float(description["dt"]) > 0:
        raise ExportError("the initial state, the first inputs or the parameters are not finite, or dt is not "
                          "positive: the FMU cannot hold them")


def _write_sources(sources: Path, step_c: str, description: dict, reference: Reference,
                   parameters: dict[str, tuple[float, str]], guid: str) -> None:
    """sources/: step.c, fmu.c, model.h, the FMI 2.0 headers (from fmpy) and buildDescription.xml."""
    try:
        import fmpy
    except ImportError as error:
        raise ExportError(f"format=fmu needs fmpy (its FMI 2.0 headers): pip install -e '.[export]' ({error})") \
            from None
    headers = Path(fmpy.__file__).parent / "c-code"
    for header in HEADERS:
        shutil.copy(headers / header, sources / header)
    (sources / "step.c").write_text(step_c, encoding="utf-8")
    (sources / "fmu.c").write_text(FMU_C, encoding="utf-8")
    (sources / "model.h").write_text(_model_h(description, reference, parameters, guid), encoding="utf-8")
    (sources / "buildDescription.xml").write_bytes(_build_description(c_identifier(description["model"])))


def _c_array(name: str, values) -> str:
    """A static const double array of ``values`` (one 0 where there are none: C99 has no empty arrays)."""
    items = [repr(float(v)) for v in values] or ["0.0"]
    return f"static const double {name}[{len(items)}] = {{{', '.join(items)}}};\n"


def _model_h(description: dict, reference: Reference, parameters: dict[str, tuple[float, str]], guid: str) -> str:
    """model.h: the GUID, the sizes, dt and the start time [s], and the start values, SI."""
    return ("/* This model's constants, for fmu.c (written by hypa.export.native): SI, times in s. */\n"
            f"#define FMU_GUID \"{guid}\"\n"
            f"#define FMU_STATE_SIZE {len(reference.initial_state)}\n"
            f"#define FMU_INPUT_SIZE {len(description['inputs'])}\n"
            f"#define FMU_OUTPUT_SIZE {len(description['outputs'])}\n"
            f"#define FMU_PARAMETER_COUNT {len(parameters)}\n"
            f"#define FMU_DT {float(description['dt'])!r}\n"
            f"#define FMU_START_TIME {float(reference.time[reference.first])!r}\n"
            + _c_array("fmu_initial_state", reference.initial_state)
            + _c_array("fmu_input_start", reference.u[reference.first])
            + _c_array("fmu_parameters", [value for value, _ in parameters.values()]))


def _build_description(name: str) -> bytes:
    """sources/buildDescription.xml (FMI 3.0's form): one C99 compilation unit, fmu.c, and libm."""
    root = ElementTree.Element("fmiBuildDescription", {"fmiVersion": "3.0"})
    configuration = ElementTree.SubElement(root, "BuildConfiguration", {
        "modelIdentifier": name, "description": "fmu.c includes step.c, model.h and the FMI 2.0 headers"})
    files = ElementTree.SubElement(configuration, "SourceFileSet", {"language": "C99"})
    ElementTree.SubElement(files, "SourceFile", {"name": "fmu.c"})
    ElementTree.SubElement(configuration, "Library", {"name": "m", "description": "the C math library"})
    ElementTree.indent(root)
    return ElementTree.tostring(root, encoding="utf-8", xml_declaration=True)


def _build_text(name: str) -> str:
    """documentation/build.txt: the command that builds the binary from the sources."""
    return (f"{name}: a source-code FMI 2.0 FMU (co-simulation and model exchange) written by hypa.\n"
            "sources/fmu.c is its one compilation unit (it includes step.c, model.h and the FMI 2.0 headers\n"
            "beside it). In the unzipped FMU's folder:\n\n"
            f"  Linux:   gcc {' '.join(LIBRARY_FLAGS)} -o binaries/linux64/{name}.so sources/fmu.c -lm\n"
            f"  macOS:   clang {' '.join(LIBRARY_FLAGS)} -o binaries/darwin64/{name}.dylib sources/fmu.c\n"
            f"  Windows: cl /nologo /LD /O2 sources\\fmu.c /Fe:binaries\\win64\\{name}.dll\n")


def _variables(description: dict, reference: Reference, slots: list[StateSlot],
               parameters: dict[str, tuple[float, str]]) -> list[tuple[dict, dict]]:
    """(ScalarVariable's attributes, Real's) of each variable, in value-reference order."""
    def variable(name, causality, variability, text, unit, start=None, initial=None):
        attributes = {"name": name, "valueReference": "", "description": text, "causality": causality,
                      "variability": variability} | ({"initial": initial} if initial else {})
        real = ({"unit": unit} if unit else {}) | ({} if start is None else {"start": repr(float(start))})
        return attributes, real

    rows = [variable(s["name"], "input", "continuous", "scheduling signal" if s.get("role") == "scheduling"
                     else "input", s["unit"], start) for s, start in zip(description["inputs"],
                                                                         reference.u[reference.first])]
    rows += [variable(s["name"], "output", "continuous", "output: the step's at the state and inputs now",
                      s["unit"]) for s in description["outputs"]]
    rows += [variable(f"initial_state[{i + 1}]", "parameter", "fixed", f"{s.block}: {s.name} ({s.kind})", s.unit,
                      start, "exact") for i, (s, start) in enumerate(zip(slots, reference.initial_state))]
    rows += [variable(f"parameter.{n}", "calculatedParameter", "fixed", PARAMETER_TEXT, unit, initial="calculated")
             for n, (_, unit) in parameters.items()]
    for vr, (attributes, _) in enumerate(rows):
        attributes["valueReference"] = str(vr)
    return rows


def _model_description(name: str, guid: str, description: dict, reference: Reference, slots: list[StateSlot],
                       parameters: dict[str, tuple[float, str]]) -> bytes:
    """modelDescription.xml (FMI 2.0): both interfaces, the units, the default experiment, the variables and
    the model structure."""
    root = ElementTree.Element("fmiModelDescription", {
        "fmiVersion": "2.0", "modelName": description["model"], "guid": guid,
        "description": f"hypa model {description['model']}: one step of {description['dt']:g} s (C, sources/step.c)",
        "generationTool": "hypa",
        "generationDateAndTime": datetime.now(timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"),
        "variableNamingConvention": "flat", "numberOfEventIndicators": "0"})
    common = {"modelIdentifier": name, "needsExecutionTool": "false", "canBeInstantiatedOnlyOncePerProcess": "false",
              "canNotUseMemoryManagementFunctions": "false", "canGetAndSetFMUstate": "false",
              "canSerializeFMUstate": "false", "providesDirectionalDerivative": "false"}
    interfaces = [("ModelExchange", {"completedIntegratorStepNotNeeded": "true"}),
                  ("CoSimulation", {"canHandleVariableCommunicationStepSize": "true", "canInterpolateInputs": "false",
                                    "maxOutputDerivativeOrder": "0", "canRunAsynchronuously": "false"})]
    for tag, own in interfaces:
        element = ElementTree.SubElement(root, tag, common | own)
        ElementTree.SubElement(ElementTree.SubElement(element, "SourceFiles"), "File", {"name": "fmu.c"})
    rows = _variables(description, reference, slots, parameters)
    units = sorted({real["unit"] for _, real in rows if "unit" in real})
    if units:
        definitions = ElementTree.SubElement(root, "UnitDefinitions")
        for unit in units:
            ElementTree.SubElement(definitions, "Unit", {"name": unit})
    categories = ElementTree.SubElement(root, "LogCategories")
    ElementTree.SubElement(categories, "Category", {"name": "logStatusError", "description": "errors"})
    ElementTree.SubElement(root, "DefaultExperiment", {"startTime": repr(float(reference.time[reference.first])),
                                                       "stepSize": repr(float(description["dt"]))})
    variables = ElementTree.SubElement(root, "ModelVariables")
    for attributes, real in rows:
        ElementTree.SubElement(ElementTree.SubElement(variables, "ScalarVariable", attributes), "Real", real)
    _model_structure(root, rows)
    ElementTree.indent(root)
    return ElementTree.tostring(root, encoding="utf-8", xml_declaration=True)


def _model_structure(root: ElementTree.Element, rows: list[tuple[dict, dict]]) -> None:
    """ModelStructure: the outputs (on every input and state), and the initial unknowns: the outputs and
    the calculated parameters (on nothing)."""
    structure = ElementTree.SubElement(root, "ModelStructure")
    causalities = [attributes["causality"] for attributes, _ in rows]
    outputs = [i + 1 for i, c in enumerate(causalities) if c == "output"]
    if outputs:
        element = ElementTree.SubElement(structure, "Outputs")
        for index in outputs:
            ElementTree.SubElement(element, "Unknown", {"index": str(index)})
    unknowns = [(i + 1, c) for i, c in enumerate(causalities) if c in ("output", "calculatedParameter")]
    if unknowns:
        element = ElementTree.SubElement(structure, "InitialUnknowns")
        for index, causality in unknowns:
            ElementTree.SubElement(element, "Unknown", {"index": str(index)}
                                   | ({"dependencies": ""} if causality == "calculatedParameter" else {}))


def _zip(root: Path, path: Path) -> None:
    """The folder ``root`` as the FMU ``path``, modelDescription.xml first."""
    files = sorted((p for p in root.rglob("*") if p.is_file()), key=lambda p: (p.name != "modelDescription.xml", p))
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as archive:
        for file in files:
            archive.write(file, file.relative_to(root).as_posix())


def _compile(command: list[str], cwd: Path, what: str) -> None:
    """Run the compiler; ``ExportError`` with its first error line when it fails."""
    result = subprocess.run(command, cwd=cwd, capture_output=True, text=True, timeout=600, check=False)
    if result.returncode != 0:
        raise ExportError(f"the C compiler ({Path(command[0]).name}) could not {what}: {_first_error(result)}")


def _first_error(result: subprocess.CompletedProcess) -> str:
    """The compiler's first error line (its first line when none says "error")."""
    lines = [line.strip() for line in (result.stderr + result.stdout).splitlines() if line.strip()]
    errors = [line for line in lines if "error" in line.lower()]
    return (errors or lines or [f"exit status {result.returncode}"])[0]


def _sources(path: Path, tmp: Path) -> Path:
    """The sources folder of an FMU (a zip, unzipped into ``tmp``), of an unzipped FMU, or ``path`` itself."""
    if path.is_file():
        with zipfile.ZipFile(path) as archive:
            archive.extractall(tmp, [n for n in archive.namelist() if n.startswith("sources/")])
        path = tmp
    sources = path / "sources" if (path / "sources").is_dir() else path
    if not (sources / "fmu.c").is_file():
        raise ExportError(f"{path} holds no FMU sources (sources/fmu.c)")
    return sources


def compile_check(path: Path) -> tuple[str, ...]:
    """Compile the FMU's sources (``path``: the FMU, its unzipped folder or its sources/) once more, C99, -O2,
    the warnings errors: the strictest of ``WARNING_LEVELS`` they pass, returned; ``ExportError`` with the
    compiler's first error line when they fail even -Wall."""
    cc = c_compiler()
    with tempfile.TemporaryDirectory() as tmp:
        sources = _sources(Path(path), Path(tmp))
        for flags in WARNING_LEVELS:
            command = [cc, "-std=c99", "-O2", *flags, "-Werror", "-c", "-o", str(Path(tmp) / "fmu.o"), "fmu.c"]
            result = subprocess.run(command, cwd=sources, capture_output=True, text=True, timeout=600, check=False)
            if result.returncode == 0:
                return flags
    raise ExportError(f"the FMU's C sources do not compile with -std=c99 -O2 {' '.join(WARNING_LEVELS[-1])} "
                      f"-Werror: {_first_error(result)}")


def validate(path: Path) -> None:
    """fmpy's validation of the FMU (its modelDescription.xml against the schema, the model structure, the
    units, the start values); ``ExportError`` listing the problems otherwise."""
    from fmpy.validation import validate_fmu

    problems = validate_fmu(str(path))
    if problems:
        raise ExportError(f"the FMU {Path(path).name} does not validate (fmpy): "
                          + "; ".join(" ".join(str(p).split()) for p in problems))


def run_native_me(path: Path, reference: Reference) -> tuple[np.ndarray, float]:
    """The FMU's model exchange through fmpy over the reference record from the sample ``first`` on: at the
    time event t_k set the inputs of sample k, run the event iteration (the state becomes state[k], state[k+1]
    is latched), read the outputs. Outputs (S, p) and the seconds per sample."""
    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Model

    description = read_model_description(str(path))
    refs = {v.name: v.valueReference for v in description.modelVariables}
    inputs, outputs = [refs[n] for n in reference.input_names], [refs[n] for n in reference.output_names]
    dt = float(description.defaultExperiment.stepSize)
    rows = reference.u[reference.first :]
    unzipped = extract(str(path))
    try:
        model = FMU2Model(guid=description.guid, unzipDirectory=unzipped,
                          modelIdentifier=description.modelExchange.modelIdentifier, instanceName="check")
        model.instantiate()
        t = float(reference.time[reference.first])
        model.setupExperiment(startTime=t)
        model.enterInitializationMode()
        model.exitInitializationMode()
        ys = []
        started = time.perf_counter()
        for k, u in enumerate(rows):
            if k > 0:  # continuous-time mode up to the time event t
                model.setTime(t)
                model.completedIntegratorStep()
                model.enterEventMode()
            model.setReal(inputs, [float(v) for v in u])
            next_time = _time_event(model, t, dt)
            ys.append(model.getReal(outputs))
            model.enterContinuousTimeMode()
            t = next_time
        seconds = (time.perf_counter() - started) / max(len(rows), 1)
        model.terminate()
        model.freeInstance()
    finally:
        shutil.rmtree(unzipped, ignore_errors=True)
    return np.array(ys, dtype=float).reshape(len(rows), -1), seconds


def _time_event(model, t: float, dt: float) -> float:
    """The event iteration at ``t`` (fmi2NewDiscreteStates until it needs no more); the next time event,
    which must be t + dt."""
    for _ in range(10):
        needed, terminate, _, _, defined, next_time = model.newDiscreteStates()
        if not needed:
            break
    if terminate or not defined or abs(next_time - (t + dt)) > 1e-6 * dt:
        raise ExportError(f"the FMU's model exchange asks for its next time event at {next_time if defined else None}"
                          f" s, not t + dt = {t + dt} s" + (" (it terminated)" if terminate else ""))
    return next_time


def time_c_step(step_c: str, state0, u_rows) -> float:
    """Seconds per step of the bare C step, compiled -O2: the rows ``u_rows`` (S, m + q) in turn from the
    state ``state0`` (r,), repeated, the steps doubled until a run takes 0.2 s or 10⁶ steps."""
    r, m, _ = step_sizes(step_c)
    state0, u_rows = np.ascontiguousarray(state0, dtype=np.float64), np.ascontiguousarray(u_rows, dtype=np.float64)
    if state0.shape != (r,) or u_rows.ndim != 2 or u_rows.shape[1] != m or len(u_rows) == 0:
        raise ExportError(f"time_c_step: the step takes a state of {r} and rows of {m} inputs, not "
                          f"{state0.shape} and {u_rows.shape}")
    cc = c_compiler()
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        (folder / "step.c").write_text(step_c, encoding="utf-8")
        (folder / "bench.c").write_text(BENCH_C, encoding="utf-8")
        data = folder / "data.bin"
        data.write_bytes(np.int64(len(u_rows)).tobytes() + state0.tobytes() + u_rows.tobytes())
        program = folder / ("bench.exe" if platform.system() == "Windows" else "bench")
        _compile([cc, "-O2", "-std=c99", "-o", str(program), "bench.c", "-lm"], folder, "build the step's benchmark")
        result = subprocess.run([str(program), str(data)], capture_output=True, text=True, timeout=600, check=False)
    if result.returncode != 0:
        raise ExportError(f"the C step's benchmark failed: {_first_error(result)}")
    return float(result.stdout.split()[0]) * 1e-9
