/* fmu-sync: FMI 2.0 co-simulation binary around a slave defined in Python.
 *
 * Written for fmu-sync (MIT). Compiled by fmu_sync.export with gcc when an FMU
 * is exported; no FMI or Python headers are needed: the FMI 2.0 types are the
 * standard ABI declared below, and every Python C-API function is looked up
 * with dlsym (no link to libpython, so a plain C host can load this file).
 *
 * Boundary:
 *   - Python (the FMU's carried code, resources/fmu_sync_code) runs only to set
 *     up an instance, to validate the parameters at fmi2ExitInitializationMode,
 *     to compute outputs in initialization mode, and to save / restore /
 *     (de)serialise FMU states. Those calls take the GIL (PyGILState_Ensure).
 *   - fmi2DoStep, fmi2GetReal/Integer and fmi2SetReal/Integer work on a plain
 *     C array of all variables (indexed by value reference) and call the numba
 *     stepper (a cfunc) through a C function pointer, without the GIL.
 *   - Python hands over, per instance: the variable array, a per-variable
 *     table (type, causality, min, max, name, allowed values), the stepper's
 *     address and its work array. Those arrays live as long as the instance.
 *
 * Compile-time definitions (from fmu_sync.export): FMU_SYNC_GUID, FMU_SYNC_BOOT
 * (module name of the boot script in resources/), FMU_SYNC_MAX_SUBSTEPS.
 */
#define _GNU_SOURCE
#include <dlfcn.h>
#include <errno.h>
#include <float.h>
#include <math.h>
#include <pthread.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <wchar.h>

#ifndef FMU_SYNC_GUID
#error "FMU_SYNC_GUID must be defined"
#endif
#ifndef FMU_SYNC_BOOT
#error "FMU_SYNC_BOOT must be defined"
#endif
#ifndef FMU_SYNC_MAX_SUBSTEPS
#define FMU_SYNC_MAX_SUBSTEPS 10000000.0
#endif
#define EXPORT __attribute__((visibility("default")))

/* ------------------------------------------------------------ FMI 2.0 ABI */
#include "fmi2_abi.h"

/* ------------------------------------------------------------ Python C API (dlsym) */
typedef struct _object PyObject;
typedef ptrdiff_t Py_ssize_t;
static struct {
    int (*IsInitialized)(void);
    void (*InitializeEx)(int);
    void (*SetProgramName)(const wchar_t *);
    wchar_t *(*DecodeLocale)(const char *, size_t *);
    void *(*EvalSaveThread)(void);
    int (*GILEnsure)(void);
    void (*GILRelease)(int);
    PyObject *(*ImportModule)(const char *);
    PyObject *(*GetAttrString)(PyObject *, const char *);
    PyObject *(*CallMethod)(PyObject *, const char *, const char *, ...);
    const char *(*UnicodeAsUTF8)(PyObject *);
    PyObject *(*UnicodeDecodeFSDefault)(const char *);
    int (*BytesAsStringAndSize)(PyObject *, char **, Py_ssize_t *);
    PyObject *(*BytesFromStringAndSize)(const char *, Py_ssize_t);
    PyObject *(*TupleGetItem)(PyObject *, Py_ssize_t);
    PyObject *(*ErrOccurred)(void);
    void (*ErrFetch)(PyObject **, PyObject **, PyObject **);
    PyObject *(*ObjectStr)(PyObject *);
    void (*DecRef)(PyObject *);
    void (*IncRef)(PyObject *);
    PyObject *None;
} py;

static pthread_mutex_t g_lock = PTHREAD_MUTEX_INITIALIZER;
static int g_py_ready = 0;          /* 1 once the API and the boot module are loaded */
static PyObject *g_boot = NULL;     /* the boot module (one per process) */

/* ------------------------------------------------------------ instance */
enum {                               /* states of the FMI 2.0 co-simulation state machine */
    ST_INSTANTIATED = 1 << 0,
    ST_INIT = 1 << 1,
    ST_STEP = 1 << 2,                /* slaveInitialized: stepComplete */
    ST_TERMINATED = 1 << 3,
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

/* variable table codes (fmus/runtime.py: TYPE_*, CAUSALITY_*) */
enum { T_REAL = 0, T_INTEGER = 1, T_ENUM = 2 };
enum { C_PARAMETER = 0, C_INPUT = 1, C_OUTPUT = 2 };

/* work array header (fmus/stepper.py: H_*) read by the C side */
enum { H_LEN = 0, H_VERSION = 1, H_TIME = 2, H_PHASE = 3, H_DT = 4, H_CONFIGURED = 5, H_M = 7, H_SCHEME = 9,
       H_ITAU = 14, H_ITAUDOT = 20 };
#define WORK_VERSION 2.0
#define SCHEME_EXACT 2.0            /* fmus/stepper.py: EXACT */

/* layout handed over by FMUInstance.layout() (fmus/runtime.py) */
enum {
    L_VERSION, L_NVARS, L_X, L_TYPE, L_CAUS, L_MIN, L_MAX, L_WORK, L_STEPPER, L_NAMES, L_HINTS,
    L_N
};
#define LAYOUT_VERSION 1

typedef int32_t (*stepper_t)(double *x, double *work, double t, double H);

typedef struct Instance {
    uint32_t magic;
    int state;
    int logging_on;
    int log_all, log_warning;       /* enabled optional categories */
    char *name;
    fmi2CallbackFunctions cb;
    PyObject *obj;                  /* the Python FMUInstance */
    unsigned nvars;
    double *x;                      /* all variables, indexed by value reference */
    const int32_t *vtype, *vcaus;
    const double *vmin, *vmax;
    double *work;
    stepper_t stepper;
    const char *names;              /* '\0'-separated, nvars entries (owned by obj) */
    const char **name_of;           /* pointers into names */
    const char **hint_of;           /* pointers into hints */
    int init_dirty;                 /* outputs must be recomputed (initialization mode) */
    double last_successful_time;
} Instance;
#define MAGIC 0x66737931u           /* "fsy1" */
#define STATE_MAGIC 0x66737353u

typedef struct {
    uint32_t magic;
    PyObject *obj;                  /* the Python state snapshot */
} SavedState;

/* ------------------------------------------------------------ logging */
/* Categories (modelDescription.xml <LogCategories>): logStatusWarning, logStatusDiscard,
 * logStatusError, logStatusFatal, logAll. Discard, Error and Fatal are always
 * passed to the logger (they carry the reason of a status); Warning and logAll
 * only with logging on. The status returned never depends on logging. */
static const char *category_of(fmi2Status s) {
    switch (s) {
    case fmi2Warning: return "logStatusWarning";
    case fmi2Discard: return "logStatusDiscard";
    case fmi2Error: return "logStatusError";
    case fmi2Fatal: return "logStatusFatal";
    default: return "logAll";
    }
}

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
    logger(env, name ? name : "?", status, category_of(status), buf);
}

static int wants(const Instance *c, fmi2Status s) {
    if (s >= fmi2Discard) return 1;
    if (!c->logging_on) return 0;
    if (s == fmi2Warning) return c->log_warning || c->log_all;
    return c->log_all;
}

static void logf_(Instance *c, fmi2Status s, const char *fmt, ...) __attribute__((format(printf, 3, 4)));
static void logf_(Instance *c, fmi2Status s, const char *fmt, ...) {
    if (!c || !c->cb.logger || !wants(c, s)) return;
    char msg[3000];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(msg, sizeof msg, fmt, ap);
    va_end(ap);
    emit(c->cb.logger, c->cb.componentEnvironment, c->name, s, msg);
}

static fmi2Status refuse(Instance *c, fmi2Status s, const char *fmt, ...) __attribute__((format(printf, 3, 4)));
static fmi2Status refuse(Instance *c, fmi2Status s, const char *fmt, ...) {
    if (c && c->cb.logger && wants(c, s)) {
        char msg[3000];
        va_list ap;
        va_start(ap, fmt);
        vsnprintf(msg, sizeof msg, fmt, ap);
        va_end(ap);
        emit(c->cb.logger, c->cb.componentEnvironment, c->name, s, msg);
    }
    return s;
}

static const char *state_name(int st) {
    switch (st) {
    case ST_INSTANTIATED: return "instantiated";
    case ST_INIT: return "initialization mode";
    case ST_STEP: return "step mode";
    case ST_TERMINATED: return "terminated";
    case ST_FATAL: return "fatal error";
    default: return "?";
    }
}

static void allowed_states(int mask, char *out, size_t n) {
    static const int all[] = {ST_INSTANTIATED, ST_INIT, ST_STEP, ST_TERMINATED};
    out[0] = '\0';
    for (size_t i = 0; i < 4; ++i)
        if (mask & all[i]) {
            if (out[0]) strncat(out, ", ", n - strlen(out) - 1);
            strncat(out, state_name(all[i]), n - strlen(out) - 1);
        }
}

/* The one check of every call: a valid instance in an allowed state. */
static int invalid(fmi2Component comp, int call, Instance **out) {
    Instance *c = (Instance *)comp;
    *out = NULL;
    if (!c) return 1;                           /* NULL component: nobody to log to */
    if (c->magic != MAGIC) return 1;
    *out = c;
    if (!(CALLS[call].mask & c->state)) {
        char allowed[200];
        allowed_states(CALLS[call].mask, allowed, sizeof allowed);
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

/* ------------------------------------------------------------ Python runtime */
static int load_api(void *h, char *err, size_t n) {
#define SYM(field, name)                                                          \
    do {                                                                          \
        *(void **)&py.field = dlsym(h, name);                                     \
        if (!py.field) {                                                          \
            snprintf(err, n, "the Python library lacks the symbol %s", name);     \
            return 0;                                                             \
        }                                                                         \
    } while (0)
    SYM(IsInitialized, "Py_IsInitialized");
    SYM(InitializeEx, "Py_InitializeEx");
    SYM(SetProgramName, "Py_SetProgramName");
    SYM(DecodeLocale, "Py_DecodeLocale");
    SYM(EvalSaveThread, "PyEval_SaveThread");
    SYM(GILEnsure, "PyGILState_Ensure");
    SYM(GILRelease, "PyGILState_Release");
    SYM(ImportModule, "PyImport_ImportModule");
    SYM(GetAttrString, "PyObject_GetAttrString");
    SYM(CallMethod, "PyObject_CallMethod");
    SYM(UnicodeAsUTF8, "PyUnicode_AsUTF8");
    SYM(UnicodeDecodeFSDefault, "PyUnicode_DecodeFSDefault");
    SYM(BytesAsStringAndSize, "PyBytes_AsStringAndSize");
    SYM(BytesFromStringAndSize, "PyBytes_FromStringAndSize");
    SYM(TupleGetItem, "PyTuple_GetItem");
    SYM(ErrOccurred, "PyErr_Occurred");
    SYM(ErrFetch, "PyErr_Fetch");
    SYM(ObjectStr, "PyObject_Str");
    SYM(DecRef, "Py_DecRef");
    SYM(IncRef, "Py_IncRef");
    SYM(None, "_Py_NoneStruct");
#undef SYM
    return 1;
}

/* The pending Python exception as text (clears it). */
static void py_error_text(char *out, size_t n) {
    PyObject *t = NULL, *v = NULL, *tb = NULL;
    py.ErrFetch(&t, &v, &tb);
    const char *s = NULL;
    PyObject *str = v ? py.ObjectStr(v) : (t ? py.ObjectStr(t) : NULL);
    if (str) s = py.UnicodeAsUTF8(str);
    snprintf(out, n, "%s", s ? s : "unknown Python error");
    if (str) py.DecRef(str);
    if (t) py.DecRef(t);
    if (v) py.DecRef(v);
    if (tb) py.DecRef(tb);
}

static void trim(char *s) {
    size_t k = strlen(s);
    while (k && (s[k - 1] == '\n' || s[k - 1] == '\r' || s[k - 1] == ' ')) s[--k] = '\0';
}

/* Read "key=value" from resources/fmu_sync_python.txt (written at export). */
static int read_manifest_value(const char *resdir, const char *key, char *out, size_t n) {
    char path[4096];
    snprintf(path, sizeof path, "%s/fmu_sync_python.txt", resdir);
    FILE *f = fopen(path, "r");
    if (!f) return 0;
    char line[4096];
    size_t kl = strlen(key);
    int found = 0;
    while (fgets(line, sizeof line, f)) {
        if (strncmp(line, key, kl) == 0 && line[kl] == '=') {
            snprintf(out, n, "%s", line + kl + 1);
            trim(out);
            found = 1;
            break;
        }
    }
    fclose(f);
    return found;
}

/* FMU_SYNC_PYTHON=/path/to/python: ask that interpreter where its libpython is. */
static int python_from_override(const char *exe, char *lib, size_t nl, char *err, size_t n) {
    if (strchr(exe, '\'')) {
        snprintf(err, n, "FMU_SYNC_PYTHON = %s: a path with a single quote is not supported", exe);
        return 0;
    }
    char cmd[8192];
    snprintf(cmd, sizeof cmd,
             "'%s' -c \"import os,sys,sysconfig as s;"
             "print(os.path.join(s.get_config_var('LIBDIR') or '',s.get_config_var('INSTSONAME') or ''))\" 2>/dev/null",
             exe);
    FILE *p = popen(cmd, "r");
    if (!p) {
        snprintf(err, n, "FMU_SYNC_PYTHON = %s: cannot run it (%s)", exe, strerror(errno));
        return 0;
    }
    lib[0] = '\0';
    if (!fgets(lib, (int)nl, p)) lib[0] = '\0';
    int rc = pclose(p);
    trim(lib);
    if (rc != 0 || !lib[0]) {
        snprintf(err, n, "FMU_SYNC_PYTHON = %s: not a working Python interpreter (exit status %d)", exe, rc);
        return 0;
    }
    return 1;
}

/* Load the Python C API: the host's interpreter if it runs one, else the
 * libpython recorded at export (or FMU_SYNC_PYTHON), initialised once with
 * that interpreter's environment. Then import the boot module. Holds g_lock. */
static int ensure_python(const char *resdir, char *err, size_t n) {
    if (g_py_ready) return 1;
    int (*is_init)(void) = (int (*)(void))dlsym(RTLD_DEFAULT, "Py_IsInitialized");
    int own = 0;
    if (is_init && is_init()) {
        if (!load_api(RTLD_DEFAULT, err, n)) return 0;
    } else {
        char lib[4096], program[4096];
        const char *env = getenv("FMU_SYNC_PYTHON");
        if (env && *env) {
            if (!python_from_override(env, lib, sizeof lib, err, n)) return 0;
            snprintf(program, sizeof program, "%s", env);
        } else {
            if (!read_manifest_value(resdir, "libpython", lib, sizeof lib) ||
                !read_manifest_value(resdir, "program", program, sizeof program)) {
                snprintf(err, n, "cannot read %s/fmu_sync_python.txt (libpython, program): is the FMU complete?",
                         resdir);
                return 0;
            }
        }
        void *h = dlopen(lib, RTLD_NOW | RTLD_GLOBAL);
        if (!h) {
            snprintf(err, n, "cannot load the Python library %s (%s); set FMU_SYNC_PYTHON to a Python "
                     "interpreter whose environment has numpy and numba", lib, dlerror());
            return 0;
        }
        if (!load_api(h, err, n)) return 0;
        if (!py.IsInitialized()) {
            wchar_t *w = py.DecodeLocale(program, NULL);
            if (w) py.SetProgramName(w);    /* finds that interpreter's (venv's) site-packages */
            py.InitializeEx(0);             /* no signal handlers: the host owns them */
            own = 1;
        }
    }
    int gil = own ? 0 : py.GILEnsure();
    int ok = 0;
    PyObject *sys = py.ImportModule("sys");
    PyObject *path = sys ? py.GetAttrString(sys, "path") : NULL;
    PyObject *dir = py.UnicodeDecodeFSDefault(resdir);
    if (path && dir) {
        PyObject *r = py.CallMethod(path, "insert", "iO", 0, dir);
        if (r) py.DecRef(r);
        g_boot = py.ImportModule(FMU_SYNC_BOOT);
        if (!g_boot) py_error_text(err, n);
        r = py.CallMethod(path, "remove", "O", dir);   /* leave sys.path as it was */
        if (r) py.DecRef(r);
        ok = g_boot != NULL;
    } else {
        py_error_text(err, n);
    }
    if (dir) py.DecRef(dir);
    if (path) py.DecRef(path);
    if (sys) py.DecRef(sys);
    if (own)
        py.EvalSaveThread();   /* release the GIL: later calls take it with PyGILState_Ensure */
    else
        py.GILRelease(gil);
    if (ok) g_py_ready = 1;
    else if (!err[0]) snprintf(err, n, "cannot import the FMU's boot module %s", FMU_SYNC_BOOT);
    return ok;
}

/* Log the messages of a Python reply: records separated by '\x1e', each
 * starting with I:, W:, D:, E: or F:. Returns the worst status. */
static fmi2Status log_reply(Instance *c, const char *text) {
    fmi2Status worst = fmi2OK;
    if (!text) return worst;
    const char *p = text;
    while (*p) {
        const char *end = strchr(p, '\x1e');
        size_t len = end ? (size_t)(end - p) : strlen(p);
        fmi2Status s = fmi2OK;
        if (len >= 2 && p[1] == ':') {
            switch (p[0]) {
            case 'W': s = fmi2Warning; break;
            case 'D': s = fmi2Discard; break;
            case 'E': s = fmi2Error; break;
            case 'F': s = fmi2Fatal; break;
            default: s = fmi2OK;
            }
            p += 2;
            len -= 2;
        }
        if (s > worst) worst = s;
        char msg[3000];
        snprintf(msg, sizeof msg, "%.*s", (int)len, p);
        if (c) logf_(c, s, "%s", msg);
        p += len;
        if (*p == '\x1e') ++p;
    }
    return worst;
}

/* Call a method of the Python instance that returns a reply string; log it;
 * return its worst status (fmi2Fatal if Python itself failed). */
static fmi2Status call_py(Instance *c, const char *method, const char *fmt, ...) {
    int gil = py.GILEnsure();
    PyObject *r;
    va_list ap;
    va_start(ap, fmt);
    /* PyObject_CallMethod is variadic: forward the few argument shapes used here */
    if (!fmt) {
        r = py.CallMethod(c->obj, method, NULL);
    } else if (strcmp(fmt, "O") == 0) {
        PyObject *a = va_arg(ap, PyObject *);
        r = py.CallMethod(c->obj, method, "O", a);
    } else {
        r = NULL;
    }
    va_end(ap);
    fmi2Status s;
    if (!r) {
        char err[2000];
        py_error_text(err, sizeof err);
        s = refuse(c, fmi2Fatal, "internal error in the Python slave (%s): %s", method, err);
        c->state = ST_FATAL;
    } else {
        s = log_reply(c, py.UnicodeAsUTF8(r));
        py.DecRef(r);
    }
    py.GILRelease(gil);
    return s;
}

/* ------------------------------------------------------------ URI (RFC 3986) */
static int hexval(int ch) {
    if (ch >= '0' && ch <= '9') return ch - '0';
    if (ch >= 'a' && ch <= 'f') return ch - 'a' + 10;
    if (ch >= 'A' && ch <= 'F') return ch - 'A' + 10;
    return -1;
}

/* file URI -> local path: file:/p, file:///p, file://localhost/p; %XX decoded
 * (UTF-8 bytes pass through); '+' is a plain '+' (RFC 3986, not a form). */
static int uri_to_path(const char *uri, char *out, size_t n, char *err, size_t en) {
    if (!uri || !*uri) {
        snprintf(err, en, "fmuResourceLocation is %s: this FMU needs its resources folder", uri ? "empty" : "NULL");
        return 0;
    }
    if (strncasecmp(uri, "file:", 5) != 0) {
        snprintf(err, en, "fmuResourceLocation '%s' is not a file: URI", uri);
        return 0;
    }
    const char *p = uri + 5;
    if (p[0] == '/' && p[1] == '/') {        /* authority */
        p += 2;
        const char *slash = strchr(p, '/');
        size_t alen = slash ? (size_t)(slash - p) : strlen(p);
        if (!(alen == 0 || (alen == 9 && strncasecmp(p, "localhost", 9) == 0))) {
            snprintf(err, en, "fmuResourceLocation '%s' names host '%.*s': only local files are supported",
                     uri, (int)alen, p);
            return 0;
        }
        p += alen;
    }
    if (*p != '/') {
        snprintf(err, en, "fmuResourceLocation '%s' has no absolute path", uri);
        return 0;
    }
    size_t j = 0;
    for (; *p && *p != '?' && *p != '#'; ++p) {
        int ch = (unsigned char)*p;
        if (ch == '%') {
            int a = hexval(p[1]), b = a >= 0 ? hexval(p[2]) : -1;
            if (a < 0 || b < 0) {
                snprintf(err, en, "fmuResourceLocation '%s': bad percent-encoding at '%.3s'", uri, p);
                return 0;
            }
            ch = a * 16 + b;
            if (ch == 0) {
                snprintf(err, en, "fmuResourceLocation '%s': encoded NUL byte", uri);
                return 0;
            }
            p += 2;
        }
        if (j + 1 >= n) {
            snprintf(err, en, "fmuResourceLocation '%s' is too long", uri);
            return 0;
        }
        out[j++] = (char)ch;
    }
    while (j > 1 && out[j - 1] == '/') --j;
    out[j] = '\0';
    struct stat sb;
    if (stat(out, &sb) != 0 || !S_ISDIR(sb.st_mode)) {
        snprintf(err, en, "fmuResourceLocation '%s' -> '%s' is not a folder (%s)", uri, out,
                 strerror(errno ? errno : ENOTDIR));
        return 0;
    }
    return 1;
}

/* shortest text that reads back as the same double (like Python's repr) */
static const char *G(double v) {
    static __thread char pool[8][40];
    static __thread int k;
    char *b = pool[k++ & 7];
    for (int prec = 1; prec <= 17; ++prec) {
        snprintf(b, 40, "%.*g", prec, v);
        if (strtod(b, NULL) == v || v != v) break;
    }
    return b;
}

/* ------------------------------------------------------------ helpers */
static void fmt_bound(const Instance *c, unsigned vr, char *out, size_t n) {
    double lo = c->vmin[vr], hi = c->vmax[vr];
    if (c->hint_of[vr] && c->hint_of[vr][0])
        snprintf(out, n, "one of %s", c->hint_of[vr]);
    else if (lo == DBL_MIN && isinf(hi))
        snprintf(out, n, "finite and > 0");
    else if (isinf(lo) && isinf(hi))
        snprintf(out, n, "finite");
    else if (isinf(hi))
        snprintf(out, n, "finite and >= %s", G(lo));
    else if (isinf(lo))
        snprintf(out, n, "finite and <= %s", G(hi));
    else
        snprintf(out, n, "finite, >= %s and <= %s", G(lo), G(hi));
}

static const char *caus_name(int c) {
    return c == C_PARAMETER ? "parameter" : c == C_INPUT ? "input" : "output";
}

static int check_vr(Instance *c, int call, fmi2ValueReference vr, int want_int) {
    if (vr >= c->nvars) {
        refuse(c, fmi2Error, "%s: unknown value reference %u (valid: 0..%u)", CALLS[call].name, vr,
               c->nvars - 1);
        return 0;
    }
    int is_int = c->vtype[vr] != T_REAL;
    if (is_int != want_int) {
        refuse(c, fmi2Error, "%s: value reference %u is %s, of type %s%s", CALLS[call].name, vr,
               c->name_of[vr], c->vtype[vr] == T_REAL ? "Real" : c->vtype[vr] == T_ENUM ? "Enumeration" : "Integer",
               want_int ? " (use fmi2GetReal/fmi2SetReal)" : " (use fmi2GetInteger/fmi2SetInteger)");
        return 0;
    }
    return 1;
}

/* ------------------------------------------------------------ FMI functions */
EXPORT const char *fmi2GetTypesPlatform(void) { return "default"; }
EXPORT const char *fmi2GetVersion(void) { return "2.0"; }

static void free_instance(Instance *c) {
    if (!c) return;
    /* a host freeing after its own interpreter shut down: leave the Python object alone */
    if (c->obj && py.IsInitialized && py.IsInitialized()) {
        int gil = py.GILEnsure();
        PyObject *r = py.CallMethod(c->obj, "free", NULL);
        if (r) py.DecRef(r);
        else { char e[200]; py_error_text(e, sizeof e); }
        py.DecRef(c->obj);
        py.GILRelease(gil);
    }
    free(c->name_of);
    free(c->hint_of);
    free(c->name);
    c->magic = 0;
    free(c);
}

static int take_layout(Instance *c, char *err, size_t n) {
    /* called with the GIL held */
    PyObject *r = py.CallMethod(c->obj, "layout", NULL);
    if (!r) { py_error_text(err, n); return 0; }
    char *buf = NULL;
    Py_ssize_t len = 0;
    uint64_t L[L_N];
    int ok = py.BytesAsStringAndSize(r, &buf, &len) == 0 && len == (Py_ssize_t)sizeof L;
    if (ok) memcpy(L, buf, sizeof L);
    py.DecRef(r);
    if (!ok) { snprintf(err, n, "bad layout from the Python slave"); return 0; }
    if (L[L_VERSION] != LAYOUT_VERSION) {
        snprintf(err, n, "layout version %llu, this binary expects %d", (unsigned long long)L[L_VERSION],
                 LAYOUT_VERSION);
        return 0;
    }
    c->nvars = (unsigned)L[L_NVARS];
    c->x = (double *)(uintptr_t)L[L_X];
    c->vtype = (const int32_t *)(uintptr_t)L[L_TYPE];
    c->vcaus = (const int32_t *)(uintptr_t)L[L_CAUS];
    c->vmin = (const double *)(uintptr_t)L[L_MIN];
    c->vmax = (const double *)(uintptr_t)L[L_MAX];
    c->work = (double *)(uintptr_t)L[L_WORK];
    c->stepper = (stepper_t)(uintptr_t)L[L_STEPPER];
    if (c->work[H_VERSION] != WORK_VERSION) {
        snprintf(err, n, "work array version %g, this binary expects %g", c->work[H_VERSION], WORK_VERSION);
        return 0;
    }
    c->name_of = calloc(c->nvars, sizeof(char *));
    c->hint_of = calloc(c->nvars, sizeof(char *));
    if (!c->name_of || !c->hint_of) { snprintf(err, n, "out of memory"); return 0; }
    const char *p = (const char *)(uintptr_t)L[L_NAMES];
    const char *h = (const char *)(uintptr_t)L[L_HINTS];
    for (unsigned i = 0; i < c->nvars; ++i) {
        c->name_of[i] = p;
        p += strlen(p) + 1;
        c->hint_of[i] = h;
        h += strlen(h) + 1;
    }
    return 1;
}

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
    if (!uri_to_path(fmuResourceLocation, resdir, sizeof resdir, err, sizeof err))
        FAIL("fmi2Instantiate: %s", err);

    pthread_mutex_lock(&g_lock);
    int ok = ensure_python(resdir, err, sizeof err);
    pthread_mutex_unlock(&g_lock);
    if (!ok) FAIL("fmi2Instantiate: %s", err);

    Instance *c = calloc(1, sizeof *c);
    if (!c) FAIL("fmi2Instantiate: out of memory");
    c->magic = MAGIC;
    c->cb = *functions;
    c->name = strdup(name);
    c->logging_on = loggingOn ? 1 : 0;
    c->log_all = c->log_warning = 1;
    c->state = ST_INSTANTIATED;

    int gil = py.GILEnsure();
    PyObject *dir = py.UnicodeDecodeFSDefault(resdir);
    PyObject *r = dir ? py.CallMethod(g_boot, "instantiate", "Oss", dir, name, fmuGUID) : NULL;
    if (dir) py.DecRef(dir);
    fmi2Status s = fmi2OK;
    if (!r) {
        py_error_text(err, sizeof err);
        s = fmi2Error;
    } else {
        PyObject *msg = py.TupleGetItem(r, 0), *obj = py.TupleGetItem(r, 1);
        s = log_reply(c, msg ? py.UnicodeAsUTF8(msg) : "E:bad reply from the boot module");
        if (obj && obj != py.None && s < fmi2Error) {
            py.IncRef(obj);
            c->obj = obj;
            if (!take_layout(c, err, sizeof err)) s = fmi2Error;
        }
        py.DecRef(r);
    }
    py.GILRelease(gil);
    if (s >= fmi2Error || !c->obj) {
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
    c->logging_on = loggingOn ? 1 : 0;
    if (n == 0) {
        c->log_all = c->log_warning = 1;
        return fmi2OK;
    }
    if (!categories) return refuse(c, fmi2Error, "fmi2SetDebugLogging: %zu categories but categories is NULL", n);
    c->log_all = c->log_warning = 0;
    for (size_t i = 0; i < n; ++i) {
        const char *k = categories[i];
        if (!k) return refuse(c, fmi2Error, "fmi2SetDebugLogging: category %zu is NULL", i);
        if (!strcmp(k, "logAll")) c->log_all = 1;
        else if (!strcmp(k, "logStatusWarning")) c->log_warning = 1;
        else if (strcmp(k, "logStatusDiscard") && strcmp(k, "logStatusError") && strcmp(k, "logStatusFatal"))
            return refuse(c, fmi2Error, "fmi2SetDebugLogging: unknown log category '%s' (known: logStatusWarning, "
                          "logStatusDiscard, logStatusError, logStatusFatal, logAll)", k);
    }
    return fmi2OK;
}

EXPORT fmi2Status fmi2SetupExperiment(fmi2Component comp, fmi2Boolean toleranceDefined, fmi2Real tolerance,
                                      fmi2Real startTime, fmi2Boolean stopTimeDefined, fmi2Real stopTime) {
    Instance *c;
    (void)toleranceDefined; (void)tolerance;
    if (invalid(comp, F_SetupExperiment, &c)) return fmi2Error;
    if (!isfinite(startTime))
        return refuse(c, fmi2Error, "fmi2SetupExperiment: startTime = %g rejected: must be finite", startTime);
    if (stopTimeDefined && !(stopTime >= startTime))
        return refuse(c, fmi2Error, "fmi2SetupExperiment: stopTime = %s must be >= startTime = %s",
                      G(stopTime), G(startTime));
    c->work[H_TIME] = startTime;
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
    fmi2Status s = call_py(c, "exit_initialization", NULL);
    if (s >= fmi2Error) return s;        /* stays in initialization mode: fix the parameters and retry */
    c->init_dirty = 0;
    c->state = ST_STEP;
    c->last_successful_time = c->work[H_TIME];
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
    fmi2Status s = call_py(c, "reset", NULL);
    if (s >= fmi2Error) return s;
    c->state = ST_INSTANTIATED;
    c->last_successful_time = c->work[H_TIME];
    return s;
}

static fmi2Status refresh_if_dirty(Instance *c) {
    if (c->state == ST_INIT && c->init_dirty) {
        fmi2Status s = call_py(c, "refresh", NULL);
        if (s >= fmi2Error) return s;
        c->init_dirty = 0;
    }
    return fmi2OK;
}

EXPORT fmi2Status fmi2GetReal(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr, fmi2Real value[]) {
    Instance *c;
    if (invalid(comp, F_GetReal, &c)) return fmi2Error;
    if (nvr && (!vr || !value)) return refuse(c, fmi2Error, "fmi2GetReal: NULL vr or value array");
    if (refresh_if_dirty(c) >= fmi2Error) return fmi2Error;
    for (size_t i = 0; i < nvr; ++i) {
        if (!check_vr(c, F_GetReal, vr[i], 0)) return fmi2Error;
        value[i] = c->x[vr[i]];
    }
    return fmi2OK;
}

EXPORT fmi2Status fmi2GetInteger(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr,
                                 fmi2Integer value[]) {
    Instance *c;
    if (invalid(comp, F_GetInteger, &c)) return fmi2Error;
    if (nvr && (!vr || !value)) return refuse(c, fmi2Error, "fmi2GetInteger: NULL vr or value array");
    if (refresh_if_dirty(c) >= fmi2Error) return fmi2Error;
    for (size_t i = 0; i < nvr; ++i) {
        if (!check_vr(c, F_GetInteger, vr[i], 1)) return fmi2Error;
        double v = c->x[vr[i]];
        if (!(v >= -2147483648.0 && v <= 2147483647.0))
            return refuse(c, fmi2Error, "fmi2GetInteger: %s = %s does not fit an fmi2Integer",
                          c->name_of[vr[i]], G(v));
        value[i] = (fmi2Integer)v;
    }
    return fmi2OK;
}

static fmi2Status set_value(Instance *c, int call, fmi2ValueReference vr, double v, int is_int) {
    if (!check_vr(c, call, vr, is_int)) return fmi2Error;
    int caus = c->vcaus[vr];
    const char *nm = c->name_of[vr];
    if (caus == C_OUTPUT)
        return refuse(c, fmi2Error, "%s: %s is an output: it cannot be set", CALLS[call].name, nm);
    if (caus == C_PARAMETER && !(c->state & (ST_INSTANTIATED | ST_INIT)))
        return refuse(c, fmi2Error, "%s: cannot set parameter %s in %s (variability fixed: only before "
                      "fmi2ExitInitializationMode)", CALLS[call].name, nm, state_name(c->state));
    if (!isfinite(v) || v < c->vmin[vr] || v > c->vmax[vr]) {
        char bound[600];
        fmt_bound(c, vr, bound, sizeof bound);
        return refuse(c, fmi2Error, "%s: %s %s = %s rejected: must be %s; value unchanged (%s)",
                      CALLS[call].name, caus_name(caus), nm, G(v), bound, G(c->x[vr]));
    }
    c->x[vr] = v;
    if (caus == C_PARAMETER) c->init_dirty = 1;
    if (caus == C_INPUT) {
        /* a new input value starts a new input polynomial: its derivative is 0
         * unless fmi2SetRealInputDerivatives sets it again (for the next doStep) */
        double *w = c->work;
        w[(size_t)w[H_ITAUDOT] + (vr - (size_t)w[H_ITAU])] = 0.0;
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

/* ------------------------------------------------------------ FMU state (Python) */
static SavedState *as_state(Instance *c, int call, fmi2FMUstate s) {
    SavedState *st = (SavedState *)s;
    if (!st || st->magic != STATE_MAGIC) {
        refuse(c, fmi2Error, "%s: not an FMU state of this FMU (NULL or freed handle)", CALLS[call].name);
        return NULL;
    }
    return st;
}

static SavedState *new_state(PyObject *obj) {
    SavedState *st = calloc(1, sizeof *st);
    if (!st) return NULL;
    st->magic = STATE_MAGIC;
    st->obj = obj;
    return st;
}

EXPORT fmi2Status fmi2GetFMUstate(fmi2Component comp, fmi2FMUstate *state) {
    Instance *c;
    if (invalid(comp, F_GetFMUstate, &c)) return fmi2Error;
    if (!state) return refuse(c, fmi2Error, "fmi2GetFMUstate: state pointer is NULL");
    if (refresh_if_dirty(c) >= fmi2Error) return fmi2Error;
    c->work[H_PHASE] = c->state;
    int gil = py.GILEnsure();
    PyObject *r = py.CallMethod(c->obj, "get_state", NULL);
    fmi2Status s = fmi2OK;
    if (!r) {
        char err[2000];
        py_error_text(err, sizeof err);
        s = refuse(c, fmi2Error, "fmi2GetFMUstate: %s", err);
    } else if (*state && ((SavedState *)*state)->magic == STATE_MAGIC) {
        /* FMI 2.0: a non-NULL state is overwritten in place */
        SavedState *old = (SavedState *)*state;
        py.DecRef(old->obj);
        old->obj = r;
    } else {
        SavedState *st = new_state(r);
        if (!st) { py.DecRef(r); s = refuse(c, fmi2Error, "fmi2GetFMUstate: out of memory"); }
        else *state = st;
    }
    py.GILRelease(gil);
    return s;
}

EXPORT fmi2Status fmi2SetFMUstate(fmi2Component comp, fmi2FMUstate state) {
    Instance *c;
    if (invalid(comp, F_SetFMUstate, &c)) return fmi2Error;
    SavedState *st = as_state(c, F_SetFMUstate, state);
    if (!st) return fmi2Error;
    fmi2Status s = call_py(c, "set_state", "O", st->obj);
    if (s >= fmi2Error) return s;      /* refused: nothing changed */
    int phase = (int)c->work[H_PHASE];
    if (phase == ST_INSTANTIATED || phase == ST_INIT || phase == ST_STEP || phase == ST_TERMINATED)
        c->state = phase;
    c->init_dirty = c->state == ST_INIT;
    c->last_successful_time = c->work[H_TIME];
    return s;
}

EXPORT fmi2Status fmi2FreeFMUstate(fmi2Component comp, fmi2FMUstate *state) {
    Instance *c;
    if (invalid(comp, F_FreeFMUstate, &c)) return fmi2Error;
    if (!state || !*state) return fmi2OK;
    SavedState *st = as_state(c, F_FreeFMUstate, *state);
    if (!st) return fmi2Error;
    if (py.IsInitialized()) {
        int gil = py.GILEnsure();
        py.DecRef(st->obj);
        py.GILRelease(gil);
    }
    st->magic = 0;
    free(st);
    *state = NULL;
    return fmi2OK;
}

/* serialised bytes of a state (new reference), or NULL with the reason logged */
static PyObject *serialized(Instance *c, int call, SavedState *st) {
    PyObject *r = py.CallMethod(c->obj, "serialize", "O", st->obj);
    if (!r) {
        char err[2000];
        py_error_text(err, sizeof err);
        refuse(c, fmi2Error, "%s: %s", CALLS[call].name, err);
    }
    return r;
}

EXPORT fmi2Status fmi2SerializedFMUstateSize(fmi2Component comp, fmi2FMUstate state, size_t *size) {
    Instance *c;
    if (invalid(comp, F_SerializedSize, &c)) return fmi2Error;
    SavedState *st = as_state(c, F_SerializedSize, state);
    if (!st || !size) return st ? refuse(c, fmi2Error, "fmi2SerializedFMUstateSize: size is NULL") : fmi2Error;
    int gil = py.GILEnsure();
    PyObject *r = serialized(c, F_SerializedSize, st);
    fmi2Status s = fmi2Error;
    char *buf;
    Py_ssize_t len;
    if (r && py.BytesAsStringAndSize(r, &buf, &len) == 0) {
        *size = (size_t)len;
        s = fmi2OK;
    }
    if (r) py.DecRef(r);
    py.GILRelease(gil);
    return s;
}

EXPORT fmi2Status fmi2SerializeFMUstate(fmi2Component comp, fmi2FMUstate state, fmi2Byte out[], size_t size) {
    Instance *c;
    if (invalid(comp, F_Serialize, &c)) return fmi2Error;
    SavedState *st = as_state(c, F_Serialize, state);
    if (!st) return fmi2Error;
    if (!out && size) return refuse(c, fmi2Error, "fmi2SerializeFMUstate: buffer is NULL");
    int gil = py.GILEnsure();
    PyObject *r = serialized(c, F_Serialize, st);
    fmi2Status s = fmi2Error;
    char *buf;
    Py_ssize_t len;
    if (r && py.BytesAsStringAndSize(r, &buf, &len) == 0) {
        if ((size_t)len != size)
            refuse(c, fmi2Error, "fmi2SerializeFMUstate: buffer of %zu bytes, the state needs %zu "
                   "(fmi2SerializedFMUstateSize)", size, (size_t)len);
        else {
            memcpy(out, buf, size);
            s = fmi2OK;
        }
    }
    if (r) py.DecRef(r);
    py.GILRelease(gil);
    return s;
}

EXPORT fmi2Status fmi2DeSerializeFMUstate(fmi2Component comp, const fmi2Byte data[], size_t size,
                                          fmi2FMUstate *state) {
    Instance *c;
    if (invalid(comp, F_DeSerialize, &c)) return fmi2Error;
    if (!state || (!data && size)) return refuse(c, fmi2Error, "fmi2DeSerializeFMUstate: NULL argument");
    int gil = py.GILEnsure();
    fmi2Status s = fmi2Error;
    PyObject *b = py.BytesFromStringAndSize(data, (Py_ssize_t)size);
    PyObject *r = b ? py.CallMethod(c->obj, "deserialize", "O", b) : NULL;
    if (b) py.DecRef(b);
    if (!r) {
        char err[2000];
        py_error_text(err, sizeof err);
        refuse(c, fmi2Error, "fmi2DeSerializeFMUstate: internal error: %s", err);
    } else {
        PyObject *msg = py.TupleGetItem(r, 0), *obj = py.TupleGetItem(r, 1);
        s = log_reply(c, msg ? py.UnicodeAsUTF8(msg) : "E:bad reply");
        if (s < fmi2Error && obj && obj != py.None) {
            py.IncRef(obj);
            SavedState *st = new_state(obj);
            if (!st) { py.DecRef(obj); s = refuse(c, fmi2Error, "fmi2DeSerializeFMUstate: out of memory"); }
            else *state = st;
        } else if (s < fmi2Error) {
            s = refuse(c, fmi2Error, "fmi2DeSerializeFMUstate: no state");
        }
        py.DecRef(r);
    }
    py.GILRelease(gil);
    return s;
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
    double *w = c->work;
    int exact = w[H_CONFIGURED] != 0.0 && w[H_SCHEME] == SCHEME_EXACT;
    for (size_t i = 0; i < n; ++i) {
        if (!check_vr(c, F_SetInputDeriv, vr[i], 0)) return fmi2Error;
        const char *nm = c->name_of[vr[i]];
        if (c->vcaus[vr[i]] != C_INPUT)
            return refuse(c, fmi2Error, "fmi2SetRealInputDerivatives: %s is a %s: only inputs have derivatives; "
                          "nothing set", nm, caus_name(c->vcaus[vr[i]]));
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
        w[(size_t)w[H_ITAUDOT] + (vr[i] - (size_t)w[H_ITAU])] = value[i];
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
    double *w = c->work;
    double now = w[H_TIME];
    if (!(H > 0.0 && isfinite(H)))
        return refuse(c, fmi2Discard, "doStep(t = %s, H = %s) refused, state unchanged at t = %s: "
                      "communication step size %s rejected: must be finite and > 0", G(t), G(H), G(now), G(H));
    double tol = 1e-9 * (fabs(now) < 1.0 ? 1.0 : fabs(now));
    if (!(fabs(t - now) <= tol))
        return refuse(c, fmi2Discard, "doStep(t = %s, H = %s) refused, state unchanged at t = %s: "
                      "currentCommunicationPoint = %s is not the slave's time %s (restore a saved FMU "
                      "state to go back in time)", G(t), G(H), G(now), G(t), G(now));
    double dt = w[H_DT];
    double count = ceil(H / dt - 1e-9);       /* computed in double: cannot overflow */
    if (w[H_SCHEME] != SCHEME_EXACT && !(count <= FMU_SYNC_MAX_SUBSTEPS))   /* exact: no internal steps */
        return refuse(c, fmi2Discard, "doStep(t = %s, H = %s) refused, state unchanged: it needs "
                      "ceil(H/dt) = %.6g internal steps of solver.dt = %s, more than the limit %.0f "
                      "(FMU_SYNC_MAX_SUBSTEPS); use a smaller H or a larger solver.dt", G(t), G(H), count, G(dt),
                      (double)FMU_SYNC_MAX_SUBSTEPS);
    int32_t rc = c->stepper(c->x, w, now, H);
    if (rc == 2)
        return refuse(c, fmi2Error, "doStep(t = %s, H = %s) refused, state unchanged: solver.scheme = exact "
                      "holds the input constant over a communication step, but a non-zero input derivative "
                      "was set (fmi2SetRealInputDerivatives before fmi2ExitInitializationMode); set it to 0 "
                      "or use solver.scheme = midpoint or theta", G(t), G(H));
    if (rc != 0 && w[H_SCHEME] == SCHEME_EXACT)
        return refuse(c, fmi2Discard, "doStep(t = %s, H = %s): the exact solver could not complete the step "
                      "(more than its event limit in one step, or an undecidable contact). The step was "
                      "rolled back: state unchanged at t = %s.", G(t), G(H), G(now));
    if (rc != 0)
        return refuse(c, fmi2Discard, "doStep(t = %s, H = %s): the state became non-finite with "
                      "solver.dt = %s (a diverging scheme or an overflowing force, e.g. an input or "
                      "forcing amplitude near the float range). The step was rolled back: state "
                      "unchanged at t = %s.", G(t), G(H), G(dt), G(now));
    w[H_TIME] = now + H;
    c->last_successful_time = w[H_TIME];
    return fmi2OK;
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
