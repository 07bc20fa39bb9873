/* What every FMI glue of fmu-sync shares (fmu_sync_fmi2.c, fmu_sync_fmi3.c): the GUID guard,
 * EXPORT, freeing an instance, the experiment's checks, the log categories (modelDescription.xml <LogCategories>: fmus/slave.py LOG_CATEGORIES), which
 * messages reach the importer, the categories of fmiXSetDebugLogging, and the names of
 * the states a refused call talks about. Statuses are the runtime's (FSR_*, numerically
 * fmi2Status and fmi3Status). Header-only: each glue has its own copy. */
#ifndef FMU_SYNC_GLUE_H
#define FMU_SYNC_GLUE_H
#include <math.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmu_sync_runtime.h"

#ifndef FMU_SYNC_GUID
#error "FMU_SYNC_GUID must be defined (fmu_sync_constants.h)"
#endif
#define EXPORT __attribute__((visibility("default")))

/* free a glue's Instance (its runtime part rt, its name, then itself); NULL is a no-op */
#define FSG_FREE_INSTANCE(c)          \
    do {                              \
        if (c) {                      \
            fsr_free(&(c)->rt);       \
            free((c)->name);          \
            (c)->magic = 0;           \
            free(c);                  \
        }                             \
    } while (0)

/* the experiment (fmi2SetupExperiment, fmi3EnterInitializationMode): FSR_OK and the start time
 * and stopTime set in the runtime (every doStep checks it, fsr_step), or FSR_ERROR with the
 * reason logged under the name of the call (nothing changed) */
static inline int fsg_experiment(fsr_instance *rt, const char *call, double start, int stop_defined, double stop) {
    if (!isfinite(start))
        return fsr_logf(rt, FSR_ERROR, "%s: startTime = %s rejected: must be finite", call, fsr_g(start));
    if (stop_defined && !(stop >= start))
        return fsr_logf(rt, FSR_ERROR, "%s: stopTime = %s must be >= startTime = %s", call, fsr_g(stop),
                        fsr_g(start));
    rt->work[FSR_H_TIME] = start;
    rt->stop_defined = stop_defined ? 1 : 0;
    rt->stop_time = stop;
    return FSR_OK;
}

/* logging switched on, and the optional categories enabled */
typedef struct { int on, all, warning; } fsg_logging;

/* Discard, Error and Fatal are always passed to the logger (they carry the reason
 * of a status); Warning and logAll only with logging on. The status returned never
 * depends on logging. */
static inline const char *fsg_category(int status) {
    switch (status) {
    case FSR_WARNING: return "logStatusWarning";
    case FSR_DISCARD: return "logStatusDiscard";
    case FSR_ERROR: return "logStatusError";
    case FSR_FATAL: return "logStatusFatal";
    default: return "logAll";
    }
}

static inline int fsg_wants(const fsg_logging *lg, int status) {
    if (status >= FSR_DISCARD) return 1;
    if (!lg->on) return 0;
    return status == FSR_WARNING ? lg->warning || lg->all : lg->all;
}

#define FSG_CATEGORIES "logStatusWarning, logStatusDiscard, logStatusError, logStatusFatal, logAll"

/* fmiXSetDebugLogging(on, n, cats): 0 and the logging changed, or -1 with the reason
 * in err (nothing changed). n = 0 enables every category. */
static inline int fsg_set_logging(fsg_logging *lg, int on, size_t n, const char *const cats[], char *err, size_t en) {
    fsg_logging nl = {on ? 1 : 0, n == 0, n == 0};
    if (n && !cats) {
        snprintf(err, en, "%zu categories but categories is NULL", n);
        return -1;
    }
    for (size_t i = 0; i < n; ++i) {
        const char *k = cats[i];
        if (!k) {
            snprintf(err, en, "category %zu is NULL", i);
            return -1;
        }
        if (!strcmp(k, "logAll")) nl.all = 1;
        else if (!strcmp(k, "logStatusWarning")) nl.warning = 1;
        else if (strcmp(k, "logStatusDiscard") && strcmp(k, "logStatusError") && strcmp(k, "logStatusFatal")) {
            snprintf(err, en, "unknown log category '%s' (known: " FSG_CATEGORIES ")", k);
            return -1;
        }
    }
    *lg = nl;
    return 0;
}

/* a glue's states: code and name, in the order they are listed to the user */
typedef struct { int code; const char *name; } fsg_state;

static inline const char *fsg_state_name(const fsg_state *t, size_t k, int code) {
    for (size_t i = 0; i < k; ++i)
        if (t[i].code == code) return t[i].name;
    return "?";
}

/* "a, b, c": the names of the states in mask */
static inline void fsg_allowed(const fsg_state *t, size_t k, int mask, char *out, size_t n) {
    out[0] = '\0';
    for (size_t i = 0; i < k; ++i)
        if (mask & t[i].code) {
            if (out[0]) strncat(out, ", ", n - strlen(out) - 1);
            strncat(out, t[i].name, n - strlen(out) - 1);
        }
}
#endif
