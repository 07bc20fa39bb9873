/* fmu-sync: FMI 3.0 co-simulation glue around a slave defined in Python.
 *
 * Written for fmu-sync (MIT). Compiled by fmu_sync.export (--fmi-version 3)
 * with the Python embedding (fmu_sync_runtime.c); no FMI or Python headers are
 * needed: the FMI 3.0 types are the ABI declared in fmi3_abi.h.
 *
 * This file owns the FMI 3.0 co-simulation state machine (one table of the
 * allowed states per call, CALLS below), the statuses and the logger; the
 * Python instance, the FMU states and the communication step are the runtime's
 * (fmu_sync_runtime.h). What FMI 3.0 adds here:
 *   - Float64 / Int64 / Enumeration variables, arrays (an array's value reference
 *     is its first scalar's slot; the runtime's work array holds each slot's size,
 *     FSR_H_ICOUNT), the independent variable time (value reference = number of slots);
 *   - early return (earlyReturnAllowed): doStep stops at the first impact of the
 *     step (the stepper's FSR_H_MODE, fmus/stepper.py) and reports earlyReturn and
 *     lastSuccessfulTime; with eventModeUsed also eventHandlingNeeded, and the
 *     exact scheme stops just before the impact, which fmi3UpdateDiscreteStates
 *     applies in event mode. Without early return the impacts are handled inside
 *     the step: the numbers of the FMI 2.0 FMU.
 *
 * FMU_SYNC_GUID (the instantiation token) and every shared number (the FMI 3.0
 * slots FSR_H_MODE .. FSR_H_ICOUNT and step modes FSR_MODE_* included) come from
 * fmu_sync_constants.h (generated at export, included by fmu_sync_runtime.h).
 */
#define _GNU_SOURCE
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi3_abi.h"
#include "fmu_sync_glue.h"
#include "fmu_sync_runtime.h"
#define G fsr_g

/* states of the FMI 3.0 co-simulation state machine (the first four are the
 * runtime's phases, saved with an FMU state; event mode is fmus/slave.py's "event") */
enum {
    ST_INSTANTIATED = FSR_INSTANTIATED,
    ST_INIT = FSR_INITIALIZATION,
    ST_STEP = FSR_STEP,
    ST_TERMINATED = FSR_TERMINATED,
    ST_EVENT = FSR_EVENT,
    ST_FATAL = 1 << 5,
};
#define ST_ALIVE (ST_INSTANTIATED | ST_INIT | ST_STEP | ST_TERMINATED | ST_EVENT)
#define ST_NONE 0                      /* calls this FMU does not provide: refused in every state */

/* The table of allowed states, one row per call (FMI 3.0, section 4.3: the
 * state machine of a co-simulation FMU; what a refused call says is built from it). */
enum {
    F_SetDebugLogging, F_EnterInit, F_ExitInit, F_EnterEventMode, F_Terminate, F_Reset, F_Get, F_Set,
    F_GetFMUState, F_SetFMUState, F_FreeFMUState, F_SerializedSize, F_Serialize, F_Deserialize,
    F_UpdateDiscreteStates, F_EnterStepMode, F_DoStep, F_NotProvided, F_N
};
static const struct { const char *name; int mask; } CALLS[F_N] = {
    [F_SetDebugLogging] = {"fmi3SetDebugLogging", ST_ALIVE},
    [F_EnterInit] = {"fmi3EnterInitializationMode", ST_INSTANTIATED},
    [F_ExitInit] = {"fmi3ExitInitializationMode", ST_INIT},
    [F_EnterEventMode] = {"fmi3EnterEventMode", ST_STEP},
    [F_Terminate] = {"fmi3Terminate", ST_STEP | ST_EVENT},
    [F_Reset] = {"fmi3Reset", ST_ALIVE},
    [F_Get] = {"fmi3Get<type>", ST_INIT | ST_EVENT | ST_STEP | ST_TERMINATED},
    [F_Set] = {"fmi3Set<type>", ST_INSTANTIATED | ST_INIT | ST_EVENT | ST_STEP},
    [F_GetFMUState] = {"fmi3GetFMUState", ST_ALIVE},
    [F_SetFMUState] = {"fmi3SetFMUState", ST_ALIVE},
    [F_FreeFMUState] = {"fmi3FreeFMUState", ST_ALIVE},
    [F_SerializedSize] = {"fmi3SerializedFMUStateSize", ST_ALIVE},
    [F_Serialize] = {"fmi3SerializeFMUState", ST_ALIVE},
    [F_Deserialize] = {"fmi3DeserializeFMUState", ST_ALIVE},
    [F_UpdateDiscreteStates] = {"fmi3UpdateDiscreteStates", ST_EVENT},
    [F_EnterStepMode] = {"fmi3EnterStepMode", ST_EVENT},
    [F_DoStep] = {"fmi3DoStep", ST_STEP},
    [F_NotProvided] = {"(not provided)", ST_NONE},
};

typedef struct Instance {
    uint32_t magic;
    int state;
    fsg_logging log;                 /* logging on, enabled optional categories */
    int event_mode_used, early_return_allowed;
    int init_dirty;                  /* outputs must be recomputed (initialization mode) */
    char *name;
    fmi3InstanceEnvironment env;
    fmi3LogMessageCallback logger;
    fsr_instance rt;
} Instance;
#define MAGIC 0x66737933u            /* "fsy3" */

/* ------------------------------------------------------------ logging (categories: fmu_sync_glue.h) */
static void on_log(void *ctx, int s, const char *text) {
    Instance *c = (Instance *)ctx;
    if (!c || !c->logger || !fsg_wants(&c->log, s)) return;
    /* the runtime's replies name the FMI 3.0 calls (the build record's fmi_version) */
    c->logger(c->env, (fmi3Status)s, fsg_category(s), text);
}

/* log the reason of a status and return it (through the runtime's logger: on_log) */
#define refuse(c, s, ...) ((fmi3Status)fsr_logf(&(c)->rt, (s), __VA_ARGS__))

static const fsg_state STATES[] = {{ST_INSTANTIATED, "instantiated"}, {ST_INIT, "initialization mode"},
                                    {ST_EVENT, "event mode"}, {ST_STEP, "step mode"}, {ST_TERMINATED, "terminated"},
                                    {ST_FATAL, "fatal error"}};
#define state_name(st) fsg_state_name(STATES, 6, (st))

/* The one check of every call: a valid instance in an allowed state. */
static int invalid(fmi3Instance inst, int call, const char *name, Instance **out) {
    Instance *c = (Instance *)inst;
    *out = NULL;
    if (!c || c->magic != MAGIC) return 1;     /* nobody to log to */
    *out = c;
    if (CALLS[call].mask & c->state) return 0;
    const char *fn = name ? name : CALLS[call].name;
    if (c->state == ST_FATAL) {
        refuse(c, fmi3Error, "%s refused: the instance had a fatal error; only fmi3FreeInstance is allowed", fn);
    } else if (CALLS[call].mask == ST_NONE) {
        refuse(c, fmi3Error, "%s: not provided by this FMU (an FMI 3.0 co-simulation FMU without clocks, "
               "structural parameters, directional derivatives or Model Exchange)", fn);
    } else {
        char allowed[200];
        fsg_allowed(STATES, 5, CALLS[call].mask, allowed, sizeof allowed);
        refuse(c, fmi3Error, "%s refused in state '%s' (allowed in: %s)", fn, state_name(c->state), allowed);
    }
    return 1;
}

static fmi3Status checked(Instance *c, int s) {
    if (s >= fmi3Fatal) c->state = ST_FATAL;
    return (fmi3Status)s;
}

/* ------------------------------------------------------------ instance */
EXPORT const char *fmi3GetVersion(void) { return "3.0"; }

static void free_instance(Instance *c) { FSG_FREE_INSTANCE(c); }

EXPORT fmi3Instance fmi3InstantiateCoSimulation(
    fmi3String instanceName, fmi3String token, fmi3String resourcePath, fmi3Boolean visible,
    fmi3Boolean loggingOn, fmi3Boolean eventModeUsed, fmi3Boolean earlyReturnAllowed,
    const fmi3ValueReference requiredIntermediateVariables[], size_t nRequiredIntermediateVariables,
    fmi3InstanceEnvironment env, fmi3LogMessageCallback logMessage, fmi3IntermediateUpdateCallback intermediateUpdate) {
    (void)visible; (void)requiredIntermediateVariables; (void)intermediateUpdate;
    Instance tmp = {.logger = logMessage, .env = env, .log = {1, 1, 1}, .rt = {.log = on_log}};
    tmp.rt.log_ctx = &tmp;
    char err[3000] = "", resdir[4096];
#define FAIL(...)                                              \
    do {                                                       \
        refuse(&tmp, fmi3Error, __VA_ARGS__);                  \
        return NULL;                                           \
    } while (0)
    if (!instanceName || !*instanceName) FAIL("fmi3InstantiateCoSimulation: instanceName must be a non-empty string");
    if (!token || strcmp(token, FMU_SYNC_GUID) != 0)
        FAIL("fmi3InstantiateCoSimulation: instantiationToken '%s' does not match this FMU's '%s' "
             "(modelDescription.xml of another FMU or another export?)", token ? token : "(NULL)", FMU_SYNC_GUID);
    if (nRequiredIntermediateVariables > 0)
        FAIL("fmi3InstantiateCoSimulation: %zu required intermediate variables: this FMU has no intermediate "
             "update (providesIntermediateUpdate = false)", nRequiredIntermediateVariables);
    if (!resourcePath || !*resourcePath)
        FAIL("fmi3InstantiateCoSimulation: resourcePath is %s: this FMU needs its resources folder",
             resourcePath ? "empty" : "NULL");
    snprintf(resdir, sizeof resdir, "%s", resourcePath);
    for (size_t j = strlen(resdir); j > 1 && resdir[j - 1] == '/'; --j) resdir[j - 1] = '\0';
    if (!fsr_is_dir(resdir))
        FAIL("fmi3InstantiateCoSimulation: resourcePath '%s' is not a folder", resourcePath);
    if (!fsr_start(resdir, err, sizeof err)) FAIL("fmi3InstantiateCoSimulation: %s", err);

    Instance *c = calloc(1, sizeof *c);
    if (!c) FAIL("fmi3InstantiateCoSimulation: out of memory");
    *c = tmp;
    c->magic = MAGIC;
    c->name = strdup(instanceName);
    c->log.on = loggingOn ? 1 : 0;
    c->event_mode_used = eventModeUsed ? 1 : 0;
    c->early_return_allowed = earlyReturnAllowed ? 1 : 0;
    c->state = ST_INSTANTIATED;
    c->rt.log = on_log;
    c->rt.log_ctx = c;
    int s = fsr_new(&c->rt, resdir, instanceName, token, err, sizeof err);
    if (s >= fmi3Error) {
        if (err[0]) refuse(&tmp, fmi3Error, "fmi3InstantiateCoSimulation: %s", err);
        free_instance(c);
        return NULL;
    }
    c->rt.work[FSR_H_MODE] = !c->early_return_allowed ? FSR_MODE_FULL : c->event_mode_used ? FSR_MODE_EARLY_EVENT : FSR_MODE_EARLY;
    fsr_logf(&c->rt, fmi3OK, "fmi3InstantiateCoSimulation: %s ready (eventModeUsed = %d, earlyReturnAllowed = %d)",
             instanceName, c->event_mode_used, c->early_return_allowed);
    return c;
#undef FAIL
}

EXPORT fmi3Instance fmi3InstantiateModelExchange(fmi3String instanceName, fmi3String token, fmi3String resourcePath,
                                                 fmi3Boolean visible, fmi3Boolean loggingOn,
                                                 fmi3InstanceEnvironment env, fmi3LogMessageCallback logMessage) {
    (void)token; (void)resourcePath; (void)visible; (void)loggingOn;
    Instance tmp = {.logger = logMessage, .env = env, .rt = {.log = on_log}};
    tmp.rt.log_ctx = &tmp;
    refuse(&tmp, fmi3Error, "fmi3InstantiateModelExchange(%s): this FMU is for Co-Simulation only",
           instanceName ? instanceName : "?");
    return NULL;
}

EXPORT fmi3Instance fmi3InstantiateScheduledExecution(fmi3String instanceName, fmi3String token,
                                                      fmi3String resourcePath, fmi3Boolean visible,
                                                      fmi3Boolean loggingOn, fmi3InstanceEnvironment env,
                                                      fmi3LogMessageCallback logMessage,
                                                      fmi3ClockUpdateCallback clockUpdate,
                                                      fmi3LockPreemptionCallback lock,
                                                      fmi3UnlockPreemptionCallback unlock) {
    (void)token; (void)resourcePath; (void)visible; (void)loggingOn; (void)clockUpdate; (void)lock; (void)unlock;
    Instance tmp = {.logger = logMessage, .env = env, .rt = {.log = on_log}};
    tmp.rt.log_ctx = &tmp;
    refuse(&tmp, fmi3Error, "fmi3InstantiateScheduledExecution(%s): this FMU is for Co-Simulation only",
           instanceName ? instanceName : "?");
    return NULL;
}

EXPORT void fmi3FreeInstance(fmi3Instance inst) {
    Instance *c = (Instance *)inst;
    if (c && c->magic == MAGIC) free_instance(c);
}

EXPORT fmi3Status fmi3SetDebugLogging(fmi3Instance inst, fmi3Boolean loggingOn, size_t n, const fmi3String cats[]) {
    Instance *c;
    if (invalid(inst, F_SetDebugLogging, NULL, &c)) return fmi3Error;
    char err[300];
    if (fsg_set_logging(&c->log, loggingOn, n, cats, err, sizeof err))
        return refuse(c, fmi3Error, "fmi3SetDebugLogging: %s; logging unchanged", err);
    return fmi3OK;
}

EXPORT fmi3Status fmi3EnterInitializationMode(fmi3Instance inst, fmi3Boolean toleranceDefined, fmi3Float64 tolerance,
                                              fmi3Float64 startTime, fmi3Boolean stopTimeDefined,
                                              fmi3Float64 stopTime) {
    Instance *c;
    (void)toleranceDefined; (void)tolerance;
    if (invalid(inst, F_EnterInit, NULL, &c)) return fmi3Error;
    if (fsg_experiment(&c->rt, "fmi3EnterInitializationMode", startTime, stopTimeDefined, stopTime) != FSR_OK)
        return fmi3Error;
    c->state = ST_INIT;
    c->init_dirty = 1;
    return fmi3OK;
}

EXPORT fmi3Status fmi3ExitInitializationMode(fmi3Instance inst) {
    Instance *c;
    if (invalid(inst, F_ExitInit, NULL, &c)) return fmi3Error;
    int s = fsr_call(&c->rt, "exit_initialization");
    if (s >= fmi3Error) return checked(c, s);   /* stays in initialization mode: fix the parameters and retry */
    c->init_dirty = 0;
    c->state = c->event_mode_used ? ST_EVENT : ST_STEP;
    return (fmi3Status)s;
}

EXPORT fmi3Status fmi3EnterEventMode(fmi3Instance inst) {
    Instance *c;
    if (invalid(inst, F_EnterEventMode, NULL, &c)) return fmi3Error;
    if (!c->event_mode_used)
        return refuse(c, fmi3Error, "fmi3EnterEventMode refused: the instance was created with eventModeUsed = "
                      "false (it handles its events inside fmi3DoStep)");
    c->state = ST_EVENT;
    return fmi3OK;
}

EXPORT fmi3Status fmi3EnterStepMode(fmi3Instance inst) {
    Instance *c;
    if (invalid(inst, F_EnterStepMode, NULL, &c)) return fmi3Error;
    c->state = ST_STEP;
    return fmi3OK;
}

EXPORT fmi3Status fmi3Terminate(fmi3Instance inst) {
    Instance *c;
    if (invalid(inst, F_Terminate, NULL, &c)) return fmi3Error;
    c->state = ST_TERMINATED;
    return fmi3OK;
}

EXPORT fmi3Status fmi3Reset(fmi3Instance inst) {
    Instance *c;
    if (invalid(inst, F_Reset, NULL, &c)) return fmi3Error;
    int s = fsr_call(&c->rt, "reset");
    if (s >= fmi3Error) return checked(c, s);
    c->state = ST_INSTANTIATED;
    c->rt.stop_defined = 0;              /* as after fmi3Instantiate: no experiment set up */
    return (fmi3Status)s;
}

/* ------------------------------------------------------------ variables */
static fmi3Status refresh_if_dirty(Instance *c) {
    if (c->state == ST_INIT && c->init_dirty) {
        int s = fsr_call(&c->rt, "refresh");
        if (s >= fmi3Error) return checked(c, s);
        if (s != fmi3OK) return (fmi3Status)s;   /* outputs NaN: parameters not a valid set yet (reason logged) */
        c->init_dirty = 0;
    }
    return fmi3OK;
}

/* scalars of the FMI 3.0 variable at vr (0: no variable starts there) */
static unsigned count_of(const Instance *c, fmi3ValueReference vr) {
    return vr < c->rt.nvars ? (unsigned)c->rt.work[(size_t)c->rt.work[FSR_H_ICOUNT] + vr] : 0;
}

/* Check the value references of a get/set of type Float64 (is_int 0) or
 * Int64/Enumeration (is_int 1) and that nValues fits; 1 if fine. */
static int check_refs(Instance *c, const char *fn, const fmi3ValueReference vr[], size_t nvr, size_t nv, int is_int,
                      int allow_time) {
    size_t total = 0;
    if (nvr && !vr) { refuse(c, fmi3Error, "%s: valueReferences is NULL", fn); return 0; }
    for (size_t i = 0; i < nvr; ++i) {
        if (allow_time && vr[i] == c->rt.nvars) { total += 1; continue; }
        unsigned k = count_of(c, vr[i]);
        if (!k) {
            refuse(c, fmi3Error, "%s: unknown value reference %u (see modelDescription.xml: an array's value "
                   "reference is its first element's; time is %u)", fn, vr[i], c->rt.nvars);
            return 0;
        }
        int t = c->rt.vtype[vr[i]];
        if ((t != FSR_T_REAL) != is_int) {
            refuse(c, fmi3Error, "%s: value reference %u is %s, of type %s (use fmi3%s)", fn, vr[i],
                   c->rt.name_of[vr[i]], t == FSR_T_REAL ? "Float64" : t == FSR_T_ENUMERATION ? "Enumeration" : "Int64",
                   t == FSR_T_REAL ? "GetFloat64/fmi3SetFloat64" : "GetInt64/fmi3SetInt64");
            return 0;
        }
        total += k;
    }
    if (total != nv) {
        refuse(c, fmi3Error, "%s: nValues = %zu, the %zu value references hold %zu values", fn, nv, nvr, total);
        return 0;
    }
    return 1;
}

static fmi3Status get_values(fmi3Instance inst, const char *fn, const fmi3ValueReference vr[], size_t nvr,
                             double *dv, int64_t *iv, size_t nv) {
    Instance *c;
    if (invalid(inst, F_Get, fn, &c)) return fmi3Error;
    if (nv && !(dv || iv)) return refuse(c, fmi3Error, "%s: values is NULL", fn);
    if (!check_refs(c, fn, vr, nvr, nv, iv != NULL, dv != NULL)) return fmi3Error;
    fmi3Status st = refresh_if_dirty(c);
    if (st >= fmi3Error) return fmi3Error;
    size_t j = 0;
    for (size_t i = 0; i < nvr; ++i) {
        if (vr[i] == c->rt.nvars) { dv[j++] = c->rt.work[FSR_H_TIME]; continue; }
        for (unsigned k = 0; k < count_of(c, vr[i]); ++k, ++j) {
            double v = c->rt.x[vr[i] + k];
            if (dv) dv[j] = v;
            else iv[j] = (int64_t)v;
        }
    }
    return st;
}

/* all-or-nothing: every value is checked before any is written */
static fmi3Status set_values(fmi3Instance inst, const char *fn, const fmi3ValueReference vr[], size_t nvr,
                             const double *dv, const int64_t *iv, size_t nv) {
    Instance *c;
    if (invalid(inst, F_Set, fn, &c)) return fmi3Error;
    if (nv && !(dv || iv)) return refuse(c, fmi3Error, "%s: values is NULL", fn);
    if (nvr && vr) for (size_t i = 0; i < nvr; ++i)
        if (vr[i] == c->rt.nvars) return refuse(c, fmi3Error, "%s: time is the independent variable: it cannot be set", fn);
    if (!check_refs(c, fn, vr, nvr, nv, iv != NULL, 0)) return fmi3Error;
    for (int pass = 0; pass < 2; ++pass) {
        size_t j = 0;
        for (size_t i = 0; i < nvr; ++i) {
            unsigned r = vr[i];
            int caus = c->rt.vcaus[r];
            const char *nm = c->rt.name_of[r];
            if (caus == FSR_C_OUTPUT) return refuse(c, fmi3Error, "%s: %s is an output: it cannot be set", fn, nm);
            if (caus == FSR_C_PARAMETER && !(c->state & (ST_INSTANTIATED | ST_INIT)))
                return refuse(c, fmi3Error, "%s: cannot set parameter %s in %s (variability fixed: only before "
                              "fmi3ExitInitializationMode)", fn, nm, state_name(c->state));
            for (unsigned k = 0; k < count_of(c, r); ++k, ++j) {
                double v = dv ? dv[j] : (double)iv[j];
                if (pass == 1) { c->rt.x[r + k] = v; continue; }
                if (!isfinite(v) || v < c->rt.vmin[r + k] || v > c->rt.vmax[r + k] || (iv && (double)iv[j] != v)) {
                    char bound[600];
                    fsr_bound_text(&c->rt, r + k, bound, sizeof bound);
                    return refuse(c, fmi3Error, "%s: %s %s = %s rejected: must be %s; nothing set", fn,
                                  fsr_caus_name(caus), c->rt.name_of[r + k], G(v), bound);
                }
            }
            if (pass == 1 && caus == FSR_C_PARAMETER) c->init_dirty = 1;
        }
    }
    return fmi3OK;
}

EXPORT fmi3Status fmi3GetFloat64(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, fmi3Float64 v[], size_t nv) {
    return get_values(c, "fmi3GetFloat64", vr, nvr, v, NULL, nv);
}
EXPORT fmi3Status fmi3GetInt64(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, fmi3Int64 v[], size_t nv) {
    return get_values(c, "fmi3GetInt64", vr, nvr, NULL, v, nv);
}
EXPORT fmi3Status fmi3SetFloat64(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, const fmi3Float64 v[],
                                 size_t nv) {
    return set_values(c, "fmi3SetFloat64", vr, nvr, v, NULL, nv);
}
EXPORT fmi3Status fmi3SetInt64(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, const fmi3Int64 v[],
                               size_t nv) {
    return set_values(c, "fmi3SetInt64", vr, nvr, NULL, v, nv);
}

/* the types this FMU has no variables of: an empty call is fine, any value reference is unknown */
static fmi3Status no_such_type(fmi3Instance inst, int call, const char *fn, size_t nvr) {
    Instance *c;
    if (invalid(inst, call, fn, &c)) return fmi3Error;
    return nvr ? refuse(c, fmi3Error, "%s: this FMU has no variables of this type (Float64, Int64 and "
                        "Enumeration only)", fn) : fmi3OK;
}
#define NO_TYPE(T, CT)                                                                                        \
    EXPORT fmi3Status fmi3Get##T(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, CT v[], size_t nv) { \
        (void)vr; (void)v; (void)nv;                                                                          \
        return no_such_type(c, F_Get, "fmi3Get" #T, nvr);                                                     \
    }                                                                                                         \
    EXPORT fmi3Status fmi3Set##T(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, const CT v[],     \
                                 size_t nv) {                                                                 \
        (void)vr; (void)v; (void)nv;                                                                          \
        return no_such_type(c, F_Set, "fmi3Set" #T, nvr);                                                     \
    }
NO_TYPE(Float32, fmi3Float32)
NO_TYPE(Int8, fmi3Int8)
NO_TYPE(UInt8, fmi3UInt8)
NO_TYPE(Int16, fmi3Int16)
NO_TYPE(UInt16, fmi3UInt16)
NO_TYPE(Int32, fmi3Int32)
NO_TYPE(UInt32, fmi3UInt32)
NO_TYPE(UInt64, fmi3UInt64)
NO_TYPE(Boolean, fmi3Boolean)
NO_TYPE(String, fmi3String)

EXPORT fmi3Status fmi3GetBinary(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, size_t sizes[],
                                fmi3Binary v[], size_t nv) {
    (void)vr; (void)sizes; (void)v; (void)nv;
    return no_such_type(c, F_Get, "fmi3GetBinary", nvr);
}
EXPORT fmi3Status fmi3SetBinary(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, const size_t sizes[],
                                const fmi3Binary v[], size_t nv) {
    (void)vr; (void)sizes; (void)v; (void)nv;
    return no_such_type(c, F_Set, "fmi3SetBinary", nvr);
}

/* ------------------------------------------------------------ FMU state (runtime) */
EXPORT fmi3Status fmi3GetFMUState(fmi3Instance inst, fmi3FMUState *state) {
    Instance *c;
    if (invalid(inst, F_GetFMUState, NULL, &c)) return fmi3Error;
    if (!state) return refuse(c, fmi3Error, "fmi3GetFMUState: FMUState is NULL");
    if (refresh_if_dirty(c) >= fmi3Error) return fmi3Error;
    c->rt.work[FSR_H_PHASE] = c->state;
    return checked(c, fsr_state_get(&c->rt, "fmi3GetFMUState", (fsr_state **)state));
}

EXPORT fmi3Status fmi3SetFMUState(fmi3Instance inst, fmi3FMUState state) {
    Instance *c;
    if (invalid(inst, F_SetFMUState, NULL, &c)) return fmi3Error;
    fsr_state *st = fsr_state_of(&c->rt, "fmi3SetFMUState", state);
    if (!st) return fmi3Error;                   /* refused: nothing changed */
    fsr_state_set(&c->rt, st);
    c->state = (int)c->rt.work[FSR_H_PHASE];
    c->init_dirty = c->state == ST_INIT;         /* outputs of the restored parameters at the next read */
    return fmi3OK;
}

EXPORT fmi3Status fmi3FreeFMUState(fmi3Instance inst, fmi3FMUState *state) {
    Instance *c;
    if (invalid(inst, F_FreeFMUState, NULL, &c)) return fmi3Error;
    if (!state || !*state) return fmi3OK;
    fsr_state *st = fsr_state_of(&c->rt, "fmi3FreeFMUState", *state);
    if (!st) return fmi3Error;
    fsr_state_free(st);
    *state = NULL;
    return fmi3OK;
}

EXPORT fmi3Status fmi3SerializedFMUStateSize(fmi3Instance inst, fmi3FMUState state, size_t *size) {
    Instance *c;
    if (invalid(inst, F_SerializedSize, NULL, &c)) return fmi3Error;
    fsr_state *st = fsr_state_of(&c->rt, "fmi3SerializedFMUStateSize", state);
    if (!st) return fmi3Error;
    if (!size) return refuse(c, fmi3Error, "fmi3SerializedFMUStateSize: size is NULL");
    return checked(c, fsr_state_serialize(&c->rt, "fmi3SerializedFMUStateSize", st, NULL, 0, size));
}

EXPORT fmi3Status fmi3SerializeFMUState(fmi3Instance inst, fmi3FMUState state, fmi3Byte out[], size_t size) {
    Instance *c;
    if (invalid(inst, F_Serialize, NULL, &c)) return fmi3Error;
    fsr_state *st = fsr_state_of(&c->rt, "fmi3SerializeFMUState", state);
    if (!st) return fmi3Error;
    if (!out) return refuse(c, fmi3Error, "fmi3SerializeFMUState: serializedState is NULL");
    size_t n = 0;
    return checked(c, fsr_state_serialize(&c->rt, "fmi3SerializeFMUState", st, (char *)out, size, &n));
}

EXPORT fmi3Status fmi3DeserializeFMUState(fmi3Instance inst, const fmi3Byte data[], size_t size, fmi3FMUState *state) {
    Instance *c;
    if (invalid(inst, F_Deserialize, NULL, &c)) return fmi3Error;
    if (!state || (!data && size)) return refuse(c, fmi3Error, "fmi3DeserializeFMUState: NULL argument");
    fsr_state *st = NULL;
    int s = fsr_state_deserialize(&c->rt, "fmi3DeserializeFMUState", (const char *)data, size, &st);
    if (s < fmi3Error) {
        fsr_state *old = fsr_state_check(&c->rt, *state);   /* a state of this instance is replaced */
        if (old) fsr_state_free(old);
        *state = st;
    }
    return checked(c, s);
}

/* ------------------------------------------------------------ event mode and the step */
/* the impact an early return in event mode stopped before: applied by the stepper (no Python) */
static int apply_pending(Instance *c) {
    double *w = c->rt.work;
    if (!(w[FSR_H_PEND_P] > 0.0)) return 0;
    double mode = w[FSR_H_MODE];
    w[FSR_H_MODE] = FSR_MODE_APPLY_EVENT;
    (void)fsr_outputs(&c->rt, "fmi3UpdateDiscreteStates");   /* the stepper with H = 0 in this mode */
    w[FSR_H_MODE] = mode;
    return 1;
}

EXPORT fmi3Status fmi3UpdateDiscreteStates(fmi3Instance inst, fmi3Boolean *discreteStatesNeedUpdate,
                                           fmi3Boolean *terminateSimulation,
                                           fmi3Boolean *nominalsOfContinuousStatesChanged,
                                           fmi3Boolean *valuesOfContinuousStatesChanged,
                                           fmi3Boolean *nextEventTimeDefined, fmi3Float64 *nextEventTime) {
    Instance *c;
    if (invalid(inst, F_UpdateDiscreteStates, NULL, &c)) return fmi3Error;
    int applied = apply_pending(c);
    if (applied)
        fsr_logf(&c->rt, fmi3OK, "fmi3UpdateDiscreteStates: the impact at t = %s applied",
                 G(c->rt.work[FSR_H_TIME]));
    if (discreteStatesNeedUpdate) *discreteStatesNeedUpdate = false;
    if (terminateSimulation) *terminateSimulation = false;
    if (nominalsOfContinuousStatesChanged) *nominalsOfContinuousStatesChanged = false;
    if (valuesOfContinuousStatesChanged) *valuesOfContinuousStatesChanged = applied;
    if (nextEventTimeDefined) *nextEventTimeDefined = false;
    if (nextEventTime) *nextEventTime = 0.0;
    return fmi3OK;
}

EXPORT fmi3Status fmi3DoStep(fmi3Instance inst, fmi3Float64 t, fmi3Float64 H, fmi3Boolean noSetFMUStatePriorToCurrentPoint,
                             fmi3Boolean *eventHandlingNeeded, fmi3Boolean *terminateSimulation,
                             fmi3Boolean *earlyReturn, fmi3Float64 *lastSuccessfulTime) {
    Instance *c;
    (void)noSetFMUStatePriorToCurrentPoint;
    if (invalid(inst, F_DoStep, NULL, &c)) return fmi3Error;
    if (!eventHandlingNeeded || !terminateSimulation || !earlyReturn || !lastSuccessfulTime)
        return refuse(c, fmi3Error, "fmi3DoStep: NULL eventHandlingNeeded, terminateSimulation, earlyReturn or "
                      "lastSuccessfulTime");
    double *w = c->rt.work;
    *eventHandlingNeeded = *terminateSimulation = *earlyReturn = false;
    *lastSuccessfulTime = w[FSR_H_TIME];
    int pended = apply_pending(c);   /* the importer stepped on without event mode: the impact happens now */
    if (pended)
        fsr_logf(&c->rt, fmi3Warning, "fmi3DoStep: the impact at t = %s was pending for event mode "
                 "(fmi3EnterEventMode, fmi3UpdateDiscreteStates); applied before this step", G(w[FSR_H_TIME]));
    double now = w[FSR_H_TIME];
    int s = fsr_step(&c->rt, t, H);
    if (s >= fmi3Discard) return checked(c, s);   /* nothing changed: still at lastSuccessfulTime */
    double reached = w[FSR_H_REACHED];
    if (reached < now + H) {
        w[FSR_H_TIME] = reached;
        *earlyReturn = true;
        *eventHandlingNeeded = c->event_mode_used;
        fsr_logf(&c->rt, fmi3OK, "fmi3DoStep(t = %s, H = %s): early return at the impact, t = %s", G(t), G(H),
                 G(reached));
    }
    *lastSuccessfulTime = w[FSR_H_TIME];
    return (fmi3Status)(pended && s < fmi3Warning ? fmi3Warning : s);   /* the skipped event mode: visible */
}

/* ------------------------------------------------------------ not provided */
#define NOT_PROVIDED(name, args, ...)                                   \
    EXPORT fmi3Status name args {                                       \
        Instance *c;                                                    \
        __VA_ARGS__;                                                    \
        invalid(instance, F_NotProvided, #name, &c);                    \
        return fmi3Error;                                               \
    }
#define U(x) (void)(x)
NOT_PROVIDED(fmi3GetClock, (fmi3Instance instance, const fmi3ValueReference vr[], size_t n, fmi3Clock v[]),
             U(vr); U(n); U(v))
NOT_PROVIDED(fmi3SetClock, (fmi3Instance instance, const fmi3ValueReference vr[], size_t n, const fmi3Clock v[]),
             U(vr); U(n); U(v))
NOT_PROVIDED(fmi3GetNumberOfVariableDependencies, (fmi3Instance instance, fmi3ValueReference vr, size_t *n),
             U(vr); U(n))
NOT_PROVIDED(fmi3GetVariableDependencies, (fmi3Instance instance, fmi3ValueReference d, size_t ed[],
             fmi3ValueReference ind[], size_t ei[], fmi3DependencyKind k[], size_t n),
             U(d); U(ed); U(ind); U(ei); U(k); U(n))
NOT_PROVIDED(fmi3GetDirectionalDerivative, (fmi3Instance instance, const fmi3ValueReference u[], size_t nu,
             const fmi3ValueReference k[], size_t nk, const fmi3Float64 s[], size_t ns, fmi3Float64 r[], size_t nr),
             U(u); U(nu); U(k); U(nk); U(s); U(ns); U(r); U(nr))
NOT_PROVIDED(fmi3GetAdjointDerivative, (fmi3Instance instance, const fmi3ValueReference u[], size_t nu,
             const fmi3ValueReference k[], size_t nk, const fmi3Float64 s[], size_t ns, fmi3Float64 r[], size_t nr),
             U(u); U(nu); U(k); U(nk); U(s); U(ns); U(r); U(nr))
NOT_PROVIDED(fmi3EnterConfigurationMode, (fmi3Instance instance), )
NOT_PROVIDED(fmi3ExitConfigurationMode, (fmi3Instance instance), )
NOT_PROVIDED(fmi3GetIntervalDecimal, (fmi3Instance instance, const fmi3ValueReference vr[], size_t n,
             fmi3Float64 iv[], fmi3IntervalQualifier q[]), U(vr); U(n); U(iv); U(q))
NOT_PROVIDED(fmi3GetIntervalFraction, (fmi3Instance instance, const fmi3ValueReference vr[], size_t n,
             fmi3UInt64 cn[], fmi3UInt64 rs[], fmi3IntervalQualifier q[]), U(vr); U(n); U(cn); U(rs); U(q))
NOT_PROVIDED(fmi3GetShiftDecimal, (fmi3Instance instance, const fmi3ValueReference vr[], size_t n,
             fmi3Float64 sh[]), U(vr); U(n); U(sh))
NOT_PROVIDED(fmi3GetShiftFraction, (fmi3Instance instance, const fmi3ValueReference vr[], size_t n,
             fmi3UInt64 cn[], fmi3UInt64 rs[]), U(vr); U(n); U(cn); U(rs))
NOT_PROVIDED(fmi3SetIntervalDecimal, (fmi3Instance instance, const fmi3ValueReference vr[], size_t n,
             const fmi3Float64 iv[]), U(vr); U(n); U(iv))
NOT_PROVIDED(fmi3SetIntervalFraction, (fmi3Instance instance, const fmi3ValueReference vr[], size_t n,
             const fmi3UInt64 cn[], const fmi3UInt64 rs[]), U(vr); U(n); U(cn); U(rs))
NOT_PROVIDED(fmi3SetShiftDecimal, (fmi3Instance instance, const fmi3ValueReference vr[], size_t n,
             const fmi3Float64 sh[]), U(vr); U(n); U(sh))
NOT_PROVIDED(fmi3SetShiftFraction, (fmi3Instance instance, const fmi3ValueReference vr[], size_t n,
             const fmi3UInt64 cn[], const fmi3UInt64 rs[]), U(vr); U(n); U(cn); U(rs))
NOT_PROVIDED(fmi3EvaluateDiscreteStates, (fmi3Instance instance), )
NOT_PROVIDED(fmi3EnterContinuousTimeMode, (fmi3Instance instance), )
NOT_PROVIDED(fmi3CompletedIntegratorStep, (fmi3Instance instance, fmi3Boolean noSet, fmi3Boolean *ev,
             fmi3Boolean *term), U(noSet); U(ev); U(term))
NOT_PROVIDED(fmi3SetTime, (fmi3Instance instance, fmi3Float64 time), U(time))
NOT_PROVIDED(fmi3SetContinuousStates, (fmi3Instance instance, const fmi3Float64 x[], size_t n), U(x); U(n))
NOT_PROVIDED(fmi3GetContinuousStateDerivatives, (fmi3Instance instance, fmi3Float64 d[], size_t n), U(d); U(n))
NOT_PROVIDED(fmi3GetEventIndicators, (fmi3Instance instance, fmi3Float64 z[], size_t n), U(z); U(n))
NOT_PROVIDED(fmi3GetContinuousStates, (fmi3Instance instance, fmi3Float64 x[], size_t n), U(x); U(n))
NOT_PROVIDED(fmi3GetNominalsOfContinuousStates, (fmi3Instance instance, fmi3Float64 x[], size_t n), U(x); U(n))
NOT_PROVIDED(fmi3GetNumberOfEventIndicators, (fmi3Instance instance, size_t *n), U(n))
NOT_PROVIDED(fmi3GetNumberOfContinuousStates, (fmi3Instance instance, size_t *n), U(n))
NOT_PROVIDED(fmi3GetOutputDerivatives, (fmi3Instance instance, const fmi3ValueReference vr[], size_t n,
             const fmi3Int32 o[], fmi3Float64 v[], size_t nv), U(vr); U(n); U(o); U(v); U(nv))
NOT_PROVIDED(fmi3ActivateModelPartition, (fmi3Instance instance, fmi3ValueReference clock, fmi3Float64 t),
             U(clock); U(t))
