/* fmu-sync: the FMI 2.0 co-simulation glue around the instance runtime.
 *
 * Written for fmu-sync (MIT). Compiled by fmu_sync.export with gcc together
 * with fmu_sync_runtime.c (the Python embedding, its API in fmu_sync_runtime.h);
 * no FMI or Python headers are needed (fmi2_abi.h declares the FMI 2.0 ABI).
 *
 * In the style of Reference-FMUs' fmi2Functions.c: one table of the states in
 * which each call is allowed (bit masks, FMI 2.0 section 4.2.4), checked in one
 * place (invalid()); every refused call returns fmi2Error and logs its reason.
 * A doStep that cannot complete is fmi2Error too, the state rolled back
 * (fmi2Discard is for a step computed over a subinterval, which this FMU never
 * does; an importer would retry a discarded step forever): docs/design.md §5.1.
 * fmi2DoStep, fmi2GetReal/Integer and fmi2SetReal/Integer work on the plain C
 * array of all variables (indexed by value reference) without Python.
 *
 * FMU_SYNC_GUID and every shared number come from fmu_sync_constants.h (generated
 * at export, included by fmu_sync_runtime.h).
 */
#define _GNU_SOURCE
#include <math.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* ------------------------------------------------------------ FMI 2.0 ABI */
#include "fmi2_abi.h"
#include "fmu_sync_glue.h"
#include "fmu_sync_runtime.h"
#define G fsr_g

/* ------------------------------------------------------------ instance */
enum {                               /* states of the FMI 2.0 co-simulation state machine */
    ST_INSTANTIATED = FSR_INSTANTIATED,
    ST_INIT = FSR_INITIALIZATION,
    ST_STEP = FSR_STEP,              /* slaveInitialized: stepComplete */
    ST_TERMINATED = FSR_TERMINATED,
    ST_FATAL = 1 << 4,
};
#define ST_ANY_ALIVE (ST_INSTANTIATED | ST_INIT | ST_STEP | ST_TERMINATED)

/* The table of allowed states, one row per call (what a refused call says is
 * built from it). FMI 2.0, section 4.2.4 (state machine of a co-simulation slave). */
enum {
    F_SetDebugLogging, F_SetupExperiment, F_EnterInit, F_ExitInit, F_Terminate, F_Reset,
    F_GetReal, F_GetInteger, F_GetBoolean, F_GetString, F_SetReal, F_SetInteger, F_SetBoolean,
    F_SetString, F_GetFMUstate, F_SetFMUstate, F_FreeFMUstate, F_SerializedSize, F_Serialize,
    F_DeSerialize, F_DirDeriv, F_SetInputDeriv, F_GetOutputDeriv, F_DoStep, F_CancelStep,
    F_GetStatus, F_N
};
static const struct { const char *name; int mask; } CALLS[F_N] = {
    [F_SetDebugLogging] = {"fmi2SetDebugLogging", ST_ANY_ALIVE},
    [F_SetupExperiment] = {"fmi2SetupExperiment", ST_INSTANTIATED},
    [F_EnterInit] = {"fmi2EnterInitializationMode", ST_INSTANTIATED},
    [F_ExitInit] = {"fmi2ExitInitializationMode", ST_INIT},
    [F_Terminate] = {"fmi2Terminate", ST_STEP},
    [F_Reset] = {"fmi2Reset", ST_ANY_ALIVE},
    [F_GetReal] = {"fmi2GetReal", ST_INIT | ST_STEP | ST_TERMINATED},
    [F_GetInteger] = {"fmi2GetInteger", ST_INIT | ST_STEP | ST_TERMINATED},
    [F_GetBoolean] = {"fmi2GetBoolean", ST_INIT | ST_STEP | ST_TERMINATED},
    [F_GetString] = {"fmi2GetString", ST_INIT | ST_STEP | ST_TERMINATED},
    [F_SetReal] = {"fmi2SetReal", ST_INSTANTIATED | ST_INIT | ST_STEP},
    [F_SetInteger] = {"fmi2SetInteger", ST_INSTANTIATED | ST_INIT | ST_STEP},
    [F_SetBoolean] = {"fmi2SetBoolean", ST_INSTANTIATED | ST_INIT | ST_STEP},
    [F_SetString] = {"fmi2SetString", ST_INSTANTIATED | ST_INIT | ST_STEP},
    [F_GetFMUstate] = {"fmi2GetFMUstate", ST_ANY_ALIVE},
    [F_SetFMUstate] = {"fmi2SetFMUstate", ST_ANY_ALIVE},
    [F_FreeFMUstate] = {"fmi2FreeFMUstate", ST_ANY_ALIVE},
    [F_SerializedSize] = {"fmi2SerializedFMUstateSize", ST_ANY_ALIVE},
    [F_Serialize] = {"fmi2SerializeFMUstate", ST_ANY_ALIVE},
    [F_DeSerialize] = {"fmi2DeSerializeFMUstate", ST_ANY_ALIVE},
    [F_DirDeriv] = {"fmi2GetDirectionalDerivative", ST_INIT | ST_STEP | ST_TERMINATED},
    [F_SetInputDeriv] = {"fmi2SetRealInputDerivatives", ST_INSTANTIATED | ST_INIT | ST_STEP},
    [F_GetOutputDeriv] = {"fmi2GetRealOutputDerivatives", ST_STEP | ST_TERMINATED},
    [F_DoStep] = {"fmi2DoStep", ST_STEP},
    [F_CancelStep] = {"fmi2CancelStep", ST_STEP},
    [F_GetStatus] = {"fmi2GetStatus", ST_STEP | ST_TERMINATED},
};

typedef struct Instance {
    uint32_t magic;
    int state;
    fsg_logging log;                /* logging on, enabled optional categories */
    char *name;
    fmi2CallbackFunctions cb;
    fsr_instance rt;                /* the runtime: Python instance, variables, work array */
    int init_dirty;                 /* outputs must be recomputed (initialization mode) */
    int outputs_stale;              /* feedthrough: an input was set since the outputs were computed */
    double last_successful_time;
} Instance;
#define MAGIC 0x66737931u           /* "fsy1" */

/* ------------------------------------------------------------ logging */
/* Categories and which messages reach the logger: fmu_sync_glue.h. */
static void emit(fmi2CallbackLogger logger, fmi2ComponentEnvironment env, const char *name,
                 fmi2Status status, const char *text) {
    /* the logger's message is a printf format: escape '%' (no allocation per message) */
    if (!logger) return;              /* a host without a logger gets the statuses only */
    char buf[4096];
    size_t j = 0;
    for (const char *p = text; *p && j < sizeof buf - 2; ++p) {
        if (*p == '%') buf[j++] = '%';
        buf[j++] = *p;
    }
    buf[j] = '\0';
    logger(env, name ? name : "?", status, fsg_category(status), buf);
}

/* the runtime's log callback: every message of an instance passes here */
static void glue_log(void *ctx, int status, const char *text) {
    Instance *c = (Instance *)ctx;
    if (c && c->cb.logger && fsg_wants(&c->log, status))
        emit(c->cb.logger, c->cb.componentEnvironment, c->name, (fmi2Status)status, text);
}

/* log the reason of a status and return it */
#define refuse(c, s, ...) ((fmi2Status)fsr_logf(&(c)->rt, (s), __VA_ARGS__))
#define logf_(c, s, ...) ((void)fsr_logf(&(c)->rt, (s), __VA_ARGS__))

/* a reply method of the Python instance; a Python exception makes the instance fatal */
static fmi2Status call_py(Instance *c, const char *method) {
    int s = fsr_call(&c->rt, method);
    if (s == FSR_FATAL) c->state = ST_FATAL;
    return (fmi2Status)s;
}

static const fsg_state STATES[] = {{ST_INSTANTIATED, "instantiated"}, {ST_INIT, "initialization mode"},
                                    {ST_STEP, "step mode"}, {ST_TERMINATED, "terminated"}, {ST_FATAL, "fatal error"}};
#define state_name(st) fsg_state_name(STATES, 5, (st))

/* The one check of every call: a valid instance in an allowed state. */
static int invalid(fmi2Component comp, int call, Instance **out) {
    Instance *c = (Instance *)comp;
    *out = NULL;
    if (!c) return 1;                           /* NULL component: nobody to log to */
    if (c->magic != MAGIC) return 1;
    *out = c;
    if (!(CALLS[call].mask & c->state)) {
        char allowed[200];
        fsg_allowed(STATES, 4, CALLS[call].mask, allowed, sizeof allowed);
        if (c->state == ST_FATAL)
            refuse(c, fmi2Error, "%s refused: the instance had a fatal error; only fmi2FreeInstance is allowed",
                   CALLS[call].name);
        else
            refuse(c, fmi2Error, "%s refused in state '%s' (allowed in: %s)%s", CALLS[call].name,
                   state_name(c->state), allowed,
                   call == F_DoStep && c->state < ST_STEP ? "; call fmi2ExitInitializationMode first" : "");
        return 1;
    }
    return 0;
}

/* ------------------------------------------------------------ helpers */
static int check_vr(Instance *c, int call, fmi2ValueReference vr, int want_int) {
    const fsr_instance *rt = &c->rt;
    if (vr >= rt->nvars) {
        refuse(c, fmi2Error, "%s: unknown value reference %u (valid: 0..%u)", CALLS[call].name, vr,
               rt->nvars - 1);
        return 0;
    }
    int is_int = rt->vtype[vr] != FSR_T_REAL;
    if (is_int != want_int) {
        refuse(c, fmi2Error, "%s: value reference %u is %s, of type %s%s", CALLS[call].name, vr,
               rt->name_of[vr],
               rt->vtype[vr] == FSR_T_REAL ? "Real" : rt->vtype[vr] == FSR_T_ENUMERATION ? "Enumeration" : "Integer",
               want_int ? " (use fmi2GetReal/fmi2SetReal)" : " (use fmi2GetInteger/fmi2SetInteger)");
        return 0;
    }
    return 1;
}

/* ------------------------------------------------------------ FMI functions */
EXPORT const char *fmi2GetTypesPlatform(void) { return "default"; }
EXPORT const char *fmi2GetVersion(void) { return "2.0"; }

static void free_instance(Instance *c) { FSG_FREE_INSTANCE(c); }

EXPORT fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                                     fmi2String fmuResourceLocation, const fmi2CallbackFunctions *functions,
                                     fmi2Boolean visible, fmi2Boolean loggingOn) {
    (void)visible;
    if (!functions) return NULL;    /* FMI 2.0 requires the callbacks: no way to report anything */
    fmi2CallbackLogger logger = functions->logger;
    fmi2ComponentEnvironment env = functions->componentEnvironment;
    const char *name = instanceName ? instanceName : "?";
    char err[3000] = "", msg[3200];
#define FAIL(...)                                                        \
    do {                                                                 \
        snprintf(msg, sizeof msg, __VA_ARGS__);                          \
        emit(logger, env, name, fmi2Error, msg);                         \
        return NULL;                                                     \
    } while (0)
    if (!instanceName || !*instanceName) FAIL("fmi2Instantiate: instanceName must be a non-empty string");
    if (fmuType != fmi2CoSimulation)
        FAIL("fmi2Instantiate: fmuType %d (%s) is not supported: this FMU is for Co-Simulation only "
             "(fmi2CoSimulation = 1)", (int)fmuType, fmuType == fmi2ModelExchange ? "Model Exchange" : "unknown");
    if (!fmuGUID || strcmp(fmuGUID, FMU_SYNC_GUID) != 0)
        FAIL("fmi2Instantiate: GUID '%s' does not match this FMU's GUID '%s' (modelDescription.xml of "
             "another FMU or another export?)", fmuGUID ? fmuGUID : "(NULL)", FMU_SYNC_GUID);
    char resdir[4096];
    if (!fsr_resources_path(fmuResourceLocation, resdir, sizeof resdir, err, sizeof err))
        FAIL("fmi2Instantiate: %s", err);
    if (!fsr_start(resdir, err, sizeof err)) FAIL("fmi2Instantiate: %s", err);

    Instance *c = calloc(1, sizeof *c);
    if (!c) FAIL("fmi2Instantiate: out of memory");
    c->magic = MAGIC;
    c->cb = *functions;
    c->name = strdup(name);
    c->log = (fsg_logging){loggingOn ? 1 : 0, 1, 1};
    c->state = ST_INSTANTIATED;
    c->rt.log = glue_log;
    c->rt.log_ctx = c;
    if (fsr_new(&c->rt, resdir, name, fmuGUID, err, sizeof err) >= FSR_ERROR) {
        if (err[0]) emit(logger, env, name, fmi2Error, err);
        free_instance(c);
        return NULL;
    }
    c->init_dirty = 0;
    logf_(c, fmi2OK, "fmi2Instantiate: %s ready (GUID %s)", name, FMU_SYNC_GUID);
    return c;
#undef FAIL
}

EXPORT void fmi2FreeInstance(fmi2Component comp) {
    Instance *c = (Instance *)comp;
    if (!c || c->magic != MAGIC) return;
    free_instance(c);
}

EXPORT fmi2Status fmi2SetDebugLogging(fmi2Component comp, fmi2Boolean loggingOn, size_t n,
                                      const fmi2String categories[]) {
    Instance *c;
    if (invalid(comp, F_SetDebugLogging, &c)) return fmi2Error;
    char err[300];
    if (fsg_set_logging(&c->log, loggingOn, n, categories, err, sizeof err))
        return refuse(c, fmi2Error, "fmi2SetDebugLogging: %s; logging unchanged", err);
    return fmi2OK;
}

EXPORT fmi2Status fmi2SetupExperiment(fmi2Component comp, fmi2Boolean toleranceDefined, fmi2Real tolerance,
                                      fmi2Real startTime, fmi2Boolean stopTimeDefined, fmi2Real stopTime) {
    Instance *c;
    (void)toleranceDefined; (void)tolerance;
    if (invalid(comp, F_SetupExperiment, &c)) return fmi2Error;
    if (fsg_experiment(&c->rt, "fmi2SetupExperiment", startTime, stopTimeDefined, stopTime) != FSR_OK)
        return fmi2Error;
    c->last_successful_time = startTime;
    return fmi2OK;
}

EXPORT fmi2Status fmi2EnterInitializationMode(fmi2Component comp) {
    Instance *c;
    if (invalid(comp, F_EnterInit, &c)) return fmi2Error;
    c->state = ST_INIT;
    c->init_dirty = 1;
    return fmi2OK;
}

EXPORT fmi2Status fmi2ExitInitializationMode(fmi2Component comp) {
    Instance *c;
    if (invalid(comp, F_ExitInit, &c)) return fmi2Error;
    fmi2Status s = call_py(c, "exit_initialization");
    if (s >= fmi2Error) return s;        /* stays in initialization mode: fix the parameters and retry */
    c->init_dirty = 0;
    c->state = ST_STEP;
    c->last_successful_time = c->rt.work[FSR_H_TIME];
    return s;
}

EXPORT fmi2Status fmi2Terminate(fmi2Component comp) {
    Instance *c;
    if (invalid(comp, F_Terminate, &c)) return fmi2Error;
    c->state = ST_TERMINATED;
    return fmi2OK;
}

EXPORT fmi2Status fmi2Reset(fmi2Component comp) {
    Instance *c;
    if (invalid(comp, F_Reset, &c)) return fmi2Error;
    fmi2Status s = call_py(c, "reset");
    if (s >= fmi2Error) return s;
    c->state = ST_INSTANTIATED;
    c->rt.stop_defined = 0;              /* as after fmi2Instantiate: no experiment set up */
    c->last_successful_time = c->rt.work[FSR_H_TIME];
    return s;
}

/* Outputs up to date before they are read: in initialization mode by the Python
 * slave (parameters may have changed); after an input was set on a direct-feedthrough
 * FMU (the coupling) by the stepper, without Python. */
static fmi2Status refresh_if_dirty(Instance *c) {
    if (c->state == ST_INIT && c->init_dirty) {
        fmi2Status s = call_py(c, "refresh");
        if (s != fmi2OK) return s;   /* warning: outputs NaN, the parameters not a valid set yet (reason logged) */
        c->init_dirty = 0;
        c->outputs_stale = 0;
    }
    if (c->outputs_stale && c->state != ST_INIT) {
        fmi2Status s = (fmi2Status)fsr_outputs(&c->rt, "fmi2GetReal/fmi2GetInteger");
        if (s >= fmi2Error) return s;
        if (s == fmi2Warning) return s;   /* inputs inside the wall: stays stale, every read warns (reason logged) */
        c->outputs_stale = 0;
    }
    return fmi2OK;
}

EXPORT fmi2Status fmi2GetReal(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr, fmi2Real value[]) {
    Instance *c;
    if (invalid(comp, F_GetReal, &c)) return fmi2Error;
    if (nvr && (!vr || !value)) return refuse(c, fmi2Error, "fmi2GetReal: NULL vr or value array");
    fmi2Status s = refresh_if_dirty(c);
    if (s >= fmi2Error) return fmi2Error;
    for (size_t i = 0; i < nvr; ++i) {
        if (!check_vr(c, F_GetReal, vr[i], 0)) return fmi2Error;
        value[i] = c->rt.x[vr[i]];
    }
    return s;
}

EXPORT fmi2Status fmi2GetInteger(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr,
                                 fmi2Integer value[]) {
    Instance *c;
    if (invalid(comp, F_GetInteger, &c)) return fmi2Error;
    if (nvr && (!vr || !value)) return refuse(c, fmi2Error, "fmi2GetInteger: NULL vr or value array");
    fmi2Status s = refresh_if_dirty(c);
    if (s >= fmi2Error) return fmi2Error;
    for (size_t i = 0; i < nvr; ++i) {
        if (!check_vr(c, F_GetInteger, vr[i], 1)) return fmi2Error;
        double v = c->rt.x[vr[i]];
        if (!(v >= -2147483648.0 && v <= 2147483647.0))
            return refuse(c, fmi2Error, "fmi2GetInteger: %s = %s does not fit an fmi2Integer",
                          c->rt.name_of[vr[i]], G(v));
        value[i] = (fmi2Integer)v;
    }
    return s;
}

static fmi2Status set_value(Instance *c, int call, fmi2ValueReference vr, double v, int is_int) {
    if (!check_vr(c, call, vr, is_int)) return fmi2Error;
    int caus = c->rt.vcaus[vr];
    const char *nm = c->rt.name_of[vr];
    if (caus == FSR_C_OUTPUT)
        return refuse(c, fmi2Error, "%s: %s is an output: it cannot be set", CALLS[call].name, nm);
    if (caus == FSR_C_PARAMETER && !(c->state & (ST_INSTANTIATED | ST_INIT)))
        return refuse(c, fmi2Error, "%s: cannot set parameter %s in %s (variability fixed: only before "
                      "fmi2ExitInitializationMode)", CALLS[call].name, nm, state_name(c->state));
    if (!isfinite(v) || v < c->rt.vmin[vr] || v > c->rt.vmax[vr]) {
        char bound[600];
        fsr_bound_text(&c->rt, vr, bound, sizeof bound);
        return refuse(c, fmi2Error, "%s: %s %s = %s rejected: must be %s; value unchanged (%s)",
                      CALLS[call].name, fsr_caus_name(caus), nm, G(v), bound, G(c->rt.x[vr]));
    }
    c->rt.x[vr] = v;
    if (caus == FSR_C_PARAMETER) c->init_dirty = 1;
    if (caus == FSR_C_INPUT) {
        /* a new input value starts a new input polynomial: its derivative is 0
         * unless fmi2SetRealInputDerivatives sets it again (for the next doStep) */
        double *w = c->rt.work;
        w[(size_t)w[FSR_H_ITAUDOT] + (vr - (size_t)w[FSR_H_ITAU])] = 0.0;
        if (fsr_feedthrough(&c->rt)) {     /* outputs are functions of the inputs: recompute on read */
            if (c->state == ST_INIT) c->init_dirty = 1;
            else c->outputs_stale = 1;
        }
    }
    return fmi2OK;
}

EXPORT fmi2Status fmi2SetReal(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr,
                              const fmi2Real value[]) {
    Instance *c;
    if (invalid(comp, F_SetReal, &c)) return fmi2Error;
    if (nvr && (!vr || !value)) return refuse(c, fmi2Error, "fmi2SetReal: NULL vr or value array");
    for (size_t i = 0; i < nvr; ++i)
        if (set_value(c, F_SetReal, vr[i], value[i], 0) != fmi2OK) return fmi2Error;
    return fmi2OK;
}

EXPORT fmi2Status fmi2SetInteger(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr,
                                 const fmi2Integer value[]) {
    Instance *c;
    if (invalid(comp, F_SetInteger, &c)) return fmi2Error;
    if (nvr && (!vr || !value)) return refuse(c, fmi2Error, "fmi2SetInteger: NULL vr or value array");
    for (size_t i = 0; i < nvr; ++i)
        if (set_value(c, F_SetInteger, vr[i], (double)value[i], 1) != fmi2OK) return fmi2Error;
    return fmi2OK;
}

static fmi2Status no_such_type(fmi2Component comp, int call, size_t n, const char *type) {
    Instance *c;
    if (invalid(comp, call, &c)) return fmi2Error;
    if (n == 0) return fmi2OK;
    return refuse(c, fmi2Error, "%s: this FMU has no %s variables", CALLS[call].name, type);
}

EXPORT fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Boolean v[]) {
    (void)vr; (void)v;
    return no_such_type(c, F_GetBoolean, n, "Boolean");
}
EXPORT fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2String v[]) {
    (void)vr; (void)v;
    return no_such_type(c, F_GetString, n, "String");
}
EXPORT fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Boolean v[]) {
    (void)vr; (void)v;
    return no_such_type(c, F_SetBoolean, n, "Boolean");
}
EXPORT fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2String v[]) {
    (void)vr; (void)v;
    return no_such_type(c, F_SetString, n, "String");
}

/* ------------------------------------------------------------ FMU state (native copies) */
EXPORT fmi2Status fmi2GetFMUstate(fmi2Component comp, fmi2FMUstate *state) {
    Instance *c;
    if (invalid(comp, F_GetFMUstate, &c)) return fmi2Error;
    if (!state) return refuse(c, fmi2Error, "fmi2GetFMUstate: state pointer is NULL");
    if (refresh_if_dirty(c) >= fmi2Error) return fmi2Error;
    c->rt.work[FSR_H_PHASE] = c->state;
    return (fmi2Status)fsr_state_get(&c->rt, "fmi2GetFMUstate", (fsr_state **)state);
}

EXPORT fmi2Status fmi2SetFMUstate(fmi2Component comp, fmi2FMUstate state) {
    Instance *c;
    if (invalid(comp, F_SetFMUstate, &c)) return fmi2Error;
    fsr_state *st = fsr_state_of(&c->rt, "fmi2SetFMUstate", state);
    if (!st) return fmi2Error;           /* refused: nothing changed */
    fsr_state_set(&c->rt, st);
    c->state = (int)c->rt.work[FSR_H_PHASE];
    c->init_dirty = c->state == ST_INIT;   /* outputs of the restored parameters at the next read */
    c->outputs_stale = 0;                /* the saved outputs are those of the saved inputs */
    c->last_successful_time = c->rt.work[FSR_H_TIME];
    return fmi2OK;
}

EXPORT fmi2Status fmi2FreeFMUstate(fmi2Component comp, fmi2FMUstate *state) {
    Instance *c;
    if (invalid(comp, F_FreeFMUstate, &c)) return fmi2Error;
    if (!state || !*state) return fmi2OK;
    fsr_state *st = fsr_state_of(&c->rt, "fmi2FreeFMUstate", *state);
    if (!st) return fmi2Error;
    fsr_state_free(st);
    *state = NULL;
    return fmi2OK;
}

EXPORT fmi2Status fmi2SerializedFMUstateSize(fmi2Component comp, fmi2FMUstate state, size_t *size) {
    Instance *c;
    if (invalid(comp, F_SerializedSize, &c)) return fmi2Error;
    fsr_state *st = fsr_state_of(&c->rt, "fmi2SerializedFMUstateSize", state);
    if (!st || !size) return st ? refuse(c, fmi2Error, "fmi2SerializedFMUstateSize: size is NULL") : fmi2Error;
    return (fmi2Status)fsr_state_serialize(&c->rt, "fmi2SerializedFMUstateSize", st, NULL, 0, size);
}

EXPORT fmi2Status fmi2SerializeFMUstate(fmi2Component comp, fmi2FMUstate state, fmi2Byte out[], size_t size) {
    Instance *c;
    if (invalid(comp, F_Serialize, &c)) return fmi2Error;
    fsr_state *st = fsr_state_of(&c->rt, "fmi2SerializeFMUstate", state);
    if (!st) return fmi2Error;
    if (!out && size) return refuse(c, fmi2Error, "fmi2SerializeFMUstate: buffer is NULL");
    char empty[1];
    return (fmi2Status)fsr_state_serialize(&c->rt, "fmi2SerializeFMUstate", st, out ? out : empty, size, NULL);
}

EXPORT fmi2Status fmi2DeSerializeFMUstate(fmi2Component comp, const fmi2Byte data[], size_t size,
                                          fmi2FMUstate *state) {
    Instance *c;
    if (invalid(comp, F_DeSerialize, &c)) return fmi2Error;
    if (!state || (!data && size)) return refuse(c, fmi2Error, "fmi2DeSerializeFMUstate: NULL argument");
    return (fmi2Status)fsr_state_deserialize(&c->rt, "fmi2DeSerializeFMUstate", data, size, (fsr_state **)state);
}

/* ------------------------------------------------------------ not provided */
EXPORT fmi2Status fmi2GetDirectionalDerivative(fmi2Component comp, const fmi2ValueReference u[], size_t nu,
                                               const fmi2ValueReference z[], size_t nz, const fmi2Real dv[],
                                               fmi2Real dz[]) {
    Instance *c;
    (void)u; (void)nu; (void)z; (void)nz; (void)dv; (void)dz;
    if (invalid(comp, F_DirDeriv, &c)) return fmi2Error;
    return refuse(c, fmi2Error, "fmi2GetDirectionalDerivative: not provided (providesDirectionalDerivative = false)");
}

/* canInterpolateInputs = true: the first derivative of an input, with respect to
 * the start of the next communication step (FMI 2.0, section 4.2.3), makes the
 * next doStep use tau(t) = tau + taudot (t - t_c) (first-order hold). It applies
 * to that one doStep: the step consumes it, and setting the input again resets
 * it to 0 (zero-order hold unless the master sets a derivative again). Order 1
 * only; the call is all-or-nothing (a refused call changes nothing). */
EXPORT fmi2Status fmi2SetRealInputDerivatives(fmi2Component comp, const fmi2ValueReference vr[], size_t n,
                                              const fmi2Integer order[], const fmi2Real value[]) {
    Instance *c;
    if (invalid(comp, F_SetInputDeriv, &c)) return fmi2Error;
    if (n && (!vr || !order || !value))
        return refuse(c, fmi2Error, "fmi2SetRealInputDerivatives: NULL vr, order or value array");
    double *w = c->rt.work;
    int exact = w[FSR_H_CONFIGURED] != 0.0 && w[FSR_H_SCHEME] == FSR_SCHEME_EXACT;
    for (size_t i = 0; i < n; ++i) {
        if (!check_vr(c, F_SetInputDeriv, vr[i], 0)) return fmi2Error;
        const char *nm = c->rt.name_of[vr[i]];
        if (c->rt.vcaus[vr[i]] != FSR_C_INPUT)
            return refuse(c, fmi2Error, "fmi2SetRealInputDerivatives: %s is a %s: only inputs have derivatives; "
                          "nothing set", nm, fsr_caus_name(c->rt.vcaus[vr[i]]));
        if (order[i] != 1)
            return refuse(c, fmi2Error, "fmi2SetRealInputDerivatives: order %d of %s refused: this FMU "
                          "interpolates its inputs linearly (order 1 only%s); nothing set", (int)order[i], nm,
                          order[i] < 1 ? "; order 0 is the value itself: use fmi2SetReal" : "");
        if (!isfinite(value[i]))
            return refuse(c, fmi2Error, "fmi2SetRealInputDerivatives: d%s/dt = %s rejected: must be finite; "
                          "nothing set", nm, G(value[i]));
        if (exact && value[i] != 0.0)
            return refuse(c, fmi2Error, "fmi2SetRealInputDerivatives: d%s/dt = %s refused: solver.scheme = "
                          "exact holds the input constant over a communication step (the exact solver "
                          "needs a constant tau); only 0 is accepted, or use solver.scheme = midpoint or "
                          "theta; nothing set", nm, G(value[i]));
    }
    for (size_t i = 0; i < n; ++i)
        w[(size_t)w[FSR_H_ITAUDOT] + (vr[i] - (size_t)w[FSR_H_ITAU])] = value[i];
    return fmi2OK;
}

EXPORT fmi2Status fmi2GetRealOutputDerivatives(fmi2Component comp, const fmi2ValueReference vr[], size_t n,
                                               const fmi2Integer order[], fmi2Real value[]) {
    Instance *c;
    (void)vr; (void)n; (void)order; (void)value;
    if (invalid(comp, F_GetOutputDeriv, &c)) return fmi2Error;
    return refuse(c, fmi2Error, "fmi2GetRealOutputDerivatives: not provided (maxOutputDerivativeOrder = 0)");
}

EXPORT fmi2Status fmi2CancelStep(fmi2Component comp) {
    Instance *c;
    if (invalid(comp, F_CancelStep, &c)) return fmi2Error;
    return refuse(c, fmi2Error, "fmi2CancelStep: doStep is synchronous (canRunAsynchronuously = false)");
}

/* ------------------------------------------------------------ doStep (no Python) */
EXPORT fmi2Status fmi2DoStep(fmi2Component comp, fmi2Real t, fmi2Real H, fmi2Boolean noSetPrior) {
    Instance *c;
    (void)noSetPrior;
    if (invalid(comp, F_DoStep, &c)) return fmi2Error;
    fmi2Status s = (fmi2Status)fsr_step(&c->rt, t, H);
    if (s <= fmi2Warning) {              /* warning: the step is taken, its reason logged */
        c->last_successful_time = c->rt.work[FSR_H_TIME];
        c->outputs_stale = 0;            /* the step computed the outputs from the current inputs */
    }
    return s;
}

EXPORT fmi2Status fmi2GetStatus(fmi2Component comp, const fmi2StatusKind s, fmi2Status *value) {
    Instance *c;
    if (invalid(comp, F_GetStatus, &c)) return fmi2Error;
    (void)value;
    return refuse(c, fmi2Discard, "fmi2GetStatus(%d): no asynchronous step is pending", (int)s);
}

EXPORT fmi2Status fmi2GetRealStatus(fmi2Component comp, const fmi2StatusKind s, fmi2Real *value) {
    Instance *c;
    if (invalid(comp, F_GetStatus, &c)) return fmi2Error;
    if (!value) return refuse(c, fmi2Error, "fmi2GetRealStatus: value is NULL");
    if (s != fmi2LastSuccessfulTime)
        return refuse(c, fmi2Discard, "fmi2GetRealStatus(%d): only fmi2LastSuccessfulTime is provided", (int)s);
    *value = c->last_successful_time;
    return fmi2OK;
}

EXPORT fmi2Status fmi2GetIntegerStatus(fmi2Component comp, const fmi2StatusKind s, fmi2Integer *value) {
    Instance *c;
    (void)value;
    if (invalid(comp, F_GetStatus, &c)) return fmi2Error;
    return refuse(c, fmi2Discard, "fmi2GetIntegerStatus(%d): no integer status is provided", (int)s);
}

EXPORT fmi2Status fmi2GetBooleanStatus(fmi2Component comp, const fmi2StatusKind s, fmi2Boolean *value) {
    Instance *c;
    if (invalid(comp, F_GetStatus, &c)) return fmi2Error;
    if (!value) return refuse(c, fmi2Error, "fmi2GetBooleanStatus: value is NULL");
    if (s != fmi2Terminated)
        return refuse(c, fmi2Discard, "fmi2GetBooleanStatus(%d): only fmi2Terminated is provided", (int)s);
    *value = fmi2False;
    return fmi2OK;
}

EXPORT fmi2Status fmi2GetStringStatus(fmi2Component comp, const fmi2StatusKind s, fmi2String *value) {
    Instance *c;
    (void)value;
    if (invalid(comp, F_GetStatus, &c)) return fmi2Error;
    return refuse(c, fmi2Discard, "fmi2GetStringStatus(%d): no string status is provided", (int)s);
}
