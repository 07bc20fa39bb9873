/* fmu-sync instance runtime: the Python embedding under the FMI glue
 * (API and its contract: fmu_sync_runtime.h).
 *
 * Written for fmu-sync (MIT). No Python headers are needed: every Python C-API
 * function is looked up with dlsym (no link to libpython, so a plain C host can
 * load the FMU). Python (the FMU's carried code, resources/fmu_sync_code) runs
 * only to set up an instance, to validate the parameters at the end of
 * initialization, to compute outputs in initialization mode and to
 * (de)serialise FMU states (saving and restoring one is a copy here, no
 * Python); those calls take the GIL. The
 * communication step (fsr_step) calls the native stepper fsr_native_step (the
 * numba cfunc compiled at export and linked in, fmu_sync_native.h), without the
 * GIL, on the arrays the Python instance handed over (they live as long as the
 * instance); the Python slave gets fsr_python_step's address at instantiation.
 *
 * Constants (fmu_sync_constants.h, generated at export): FMU_SYNC_BOOT (module
 * name of the boot script in resources/), FSR_MAX_SUBSTEPS and the shared codes.
 */
#define _GNU_SOURCE
#include <dlfcn.h>
#include <errno.h>
#include <float.h>
#include <limits.h>
#include <math.h>
#include <pthread.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <fcntl.h>
#include <strings.h>
#include <unistd.h>
#include <wchar.h>

#include "fmu_sync_native.h"
#include "fmu_sync_process.h"
#include "fmu_sync_runtime.h"

/* glibc floor (docs/fmu.md "The binary"): the binary loads on glibc 2.17 (RHEL 7/8, Ubuntu
 * 20.04, Debian 11). dlopen/dlsym/dlerror moved into libc in 2.34 with new versions: bind the
 * old ones (libdl, linked with -ldl); stat/fstat are real functions only since 2.33, so none is
 * called (fsr_is_dir opens the folder instead). tests/test_fmu_portable.py checks every symbol. */
#if defined(__x86_64__) && defined(__GLIBC__)
__asm__(".symver dlopen,dlopen@GLIBC_2.2.5");
__asm__(".symver dlsym,dlsym@GLIBC_2.2.5");
__asm__(".symver dlerror,dlerror@GLIBC_2.2.5");
__asm__(".symver dladdr,dladdr@GLIBC_2.2.5");
#endif

#ifndef FMU_SYNC_BOOT
#error "FMU_SYNC_BOOT must be defined (fmu_sync_constants.h)"
#endif

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
    int (*SetAttrString)(PyObject *, const char *, PyObject *);
    PyObject *(*InternFromString)(const char *);
    PyObject *(*GetAttr)(PyObject *, PyObject *);
    PyObject *(*VaBuildValue)(const char *, va_list);
    PyObject *(*Call)(PyObject *, PyObject *, PyObject *);
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
static int g_embedded = 0;          /* 1 if this binary started the interpreter (a plain C host) */

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
    SYM(SetAttrString, "PyObject_SetAttrString");
    SYM(InternFromString, "PyUnicode_InternFromString");
    SYM(GetAttr, "PyObject_GetAttr");
    SYM(VaBuildValue, "Py_VaBuildValue");
    SYM(Call, "PyObject_Call");
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

/* An attribute name as one interned string per name, kept (GIL held). CPython's type attribute
 * cache is keyed on the name object's address and keeps a reference: a name made afresh per call
 * (PyObject_GetAttrString, PyObject_CallMethod) stays there until its slot is reused, so every
 * instantiate/free cycle grew the process by about 200 bytes (issue 35). */
static PyObject *name_obj(const char *name) {
    static struct { char key[32]; PyObject *obj; } names[24];
    static int count = 0;
    for (int i = 0; i < count; ++i)
        if (!strcmp(names[i].key, name)) return names[i].obj;
    PyObject *obj = py.InternFromString(name);
    if (obj && count < (int)(sizeof names / sizeof names[0]) && strlen(name) < sizeof names[0].key) {
        snprintf(names[count].key, sizeof names[0].key, "%s", name);
        names[count++].obj = obj;            /* the table's reference: the name stays interned */
    } else if (obj) {
        py.DecRef(obj);                      /* not kept (never for this runtime's few names) */
    }
    return obj;
}

/* obj.name (a new reference, or NULL with the exception set) */
static PyObject *get_attr(PyObject *obj, const char *name) {
    PyObject *n = name_obj(name);
    return n ? py.GetAttr(obj, n) : NULL;
}

/* obj.name(arguments built from format as Py_BuildValue builds them; NULL: none) */
static PyObject *call_method(PyObject *obj, const char *name, const char *format, ...) {
    PyObject *m = get_attr(obj, name);
    if (!m) return NULL;
    char fmt[32];
    snprintf(fmt, sizeof fmt, "(%s)", format ? format : "");
    va_list ap;
    va_start(ap, format);
    PyObject *args = py.VaBuildValue(fmt, ap);
    va_end(ap);
    PyObject *r = args ? py.Call(m, args, NULL) : NULL;
    if (args) py.DecRef(args);
    py.DecRef(m);
    return r;
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

/* ------------------------------------------------------------ one interpreter start per process
 * A host may load several fmu-sync binaries (FMUs of different models, each dlopen'ed RTLD_LOCAL:
 * each has its own statics) and instantiate them in any threads at once. They agree on who starts
 * the interpreter through one record per process (fmu_sync_process.h), exported by the small
 * library FSR_PROCESS_LIB beside each binary: a binary looks the record's symbol up with
 * dlsym(RTLD_DEFAULT) (the global scope); finding none, it loads its own copy of that library
 * RTLD_GLOBAL | RTLD_NODELETE and looks again. The global scope only grows at its end, so every
 * binary gets the record of the first copy made global, and it is never unloaded. Without that
 * library (a binary copied alone), the binary's own record. Under the record's lock:
 * Py_IsInitialized, and the start. */
static fsr_process *the_process(void) {   /* holds g_lock */
    static fsr_process own = {PTHREAD_MUTEX_INITIALIZER, 0, ""};
    static fsr_process *found = NULL;
    if (found) return found;
    fsr_process_getter f = (fsr_process_getter)dlsym(RTLD_DEFAULT, FSR_PROCESS_SYMBOL);
    Dl_info info;
    if (!f && dladdr((const void *)&the_process, &info) && info.dli_fname && strrchr(info.dli_fname, '/')) {
        char lib[PATH_MAX];
        snprintf(lib, sizeof lib, "%.*s/%s", (int)(strrchr(info.dli_fname, '/') - info.dli_fname),
                 info.dli_fname, FSR_PROCESS_LIB);
        if (dlopen(lib, RTLD_NOW | RTLD_GLOBAL | RTLD_NODELETE))
            f = (fsr_process_getter)dlsym(RTLD_DEFAULT, FSR_PROCESS_SYMBOL);
    }
    found = f ? f() : &own;
    return found;
}

/* The interpreter of this process and its C API: the running one (the host's, or one another
 * fmu-sync binary started), else the libpython fsp_find chooses, started with that interpreter's
 * environment (the GIL released at once). Holds the process lock. */
static int start_python(fsr_process *pr, const char *resdir, char *err, size_t n) {
    int (*is_init)(void) = (int (*)(void))dlsym(RTLD_DEFAULT, "Py_IsInitialized");
    if (is_init && is_init()) return load_api(RTLD_DEFAULT, err, n);
    static fsp_choice choice;
    if (!fsp_find(resdir, &choice, err, n)) return 0;
    void *h = dlopen(choice.lib, RTLD_NOW | RTLD_GLOBAL);
    if (!h) {
        snprintf(err, n, "cannot load the Python library %s of %s (%s); chosen from: %s", choice.lib,
                 choice.program, dlerror(), choice.tried);
        return 0;
    }
    if (!load_api(h, err, n)) return 0;
    if (!py.IsInitialized()) {
        wchar_t *w = py.DecodeLocale(choice.program, NULL);
        if (w) py.SetProgramName(w);    /* finds that interpreter's (venv's) site-packages */
        py.InitializeEx(0);             /* no signal handlers: the host owns them */
        py.EvalSaveThread();            /* release the GIL: every call takes it with PyGILState_Ensure */
        pr->embedded = 1;
        snprintf(pr->tried, sizeof pr->tried, "%s", choice.tried);
    }
    return 1;
}

/* The Python C API (start_python, under the process lock), then this binary's boot module
 * imported. Holds g_lock. */
static int ensure_python(const char *resdir, char *err, size_t n) {
    if (g_py_ready) return 1;
    fsr_process *pr = the_process();
    pthread_mutex_lock(&pr->lock);
    int started = start_python(pr, resdir, err, n);
    int own = pr->embedded;
    pthread_mutex_unlock(&pr->lock);
    if (!started) return 0;
    int gil = py.GILEnsure();
    int ok = 0;
    PyObject *sys = py.ImportModule("sys");
    PyObject *path = sys ? get_attr(sys, "path") : NULL;
    PyObject *dir = py.UnicodeDecodeFSDefault(resdir);
    if (path && dir) {
        PyObject *r = call_method(path, "insert", "iO", 0, dir);
        if (r) py.DecRef(r);
        g_boot = py.ImportModule(FMU_SYNC_BOOT);
        if (!g_boot) py_error_text(err, n);
        PyObject *how = g_boot && own ? py.UnicodeDecodeFSDefault(pr->tried) : NULL;
        if (how) {                      /* how this Python was chosen, for the boot's messages */
            py.SetAttrString(g_boot, "CHOSEN", how);
            py.DecRef(how);
        }
        r = call_method(path, "remove", "O", dir);   /* leave sys.path as it was */
        if (r) py.DecRef(r);
        ok = g_boot != NULL;
    } else {
        py_error_text(err, n);
    }
    if (dir) py.DecRef(dir);
    if (path) py.DecRef(path);
    if (sys) py.DecRef(sys);
    py.GILRelease(gil);
    if (ok) {
        g_py_ready = 1;
        g_embedded = own;
    }
    else if (!err[0]) snprintf(err, n, "cannot import the FMU's boot module %s", FMU_SYNC_BOOT);
    return ok;
}

int fsr_start(const char *resdir, char *err, size_t n) {
    if (!fsr_verify(resdir, err, n)) return 0;   /* nothing of a foreign or edited folder runs */
    pthread_mutex_lock(&g_lock);
    int ok = ensure_python(resdir, err, n);
    pthread_mutex_unlock(&g_lock);
    return ok;
}

int fsr_logf(fsr_instance *inst, int status, const char *fmt, ...) {
    if (inst && inst->log) {
        char msg[3000];
        va_list ap;
        va_start(ap, fmt);
        vsnprintf(msg, sizeof msg, fmt, ap);
        va_end(ap);
        inst->log(inst->log_ctx, status, msg);
    }
    return status;
}

/* Log the messages of a Python reply: records separated by '\x1e', each
 * starting with I:, W:, D:, E: or F: (the status of the call), or N: (a
 * notice: logged as a warning, the call's status stays OK). Returns the worst status. */
static int log_reply(fsr_instance *inst, const char *text) {
    int worst = FSR_OK;
    if (!text) return worst;
    const char *p = text;
    while (*p) {
        const char *end = strchr(p, '\x1e');
        size_t len = end ? (size_t)(end - p) : strlen(p);
        int s = FSR_OK, notice = 0;
        if (len >= 2 && p[1] == ':') {
            switch (p[0]) {
            case 'N': s = FSR_WARNING; notice = 1; break;
            case 'W': s = FSR_WARNING; break;
            case 'D': s = FSR_DISCARD; break;
            case 'E': s = FSR_ERROR; break;
            case 'F': s = FSR_FATAL; break;
            default: s = FSR_OK;
            }
            p += 2;
            len -= 2;
        }
        if (s > worst && !notice) worst = s;
        fsr_logf(inst, s, "%.*s", (int)len, p);
        p += len;
        if (*p == '\x1e') ++p;
    }
    return worst;
}

/* Call a method of the Python instance that returns a reply string (no
 * argument); log it; return its worst status (FSR_FATAL if Python itself failed). */
int fsr_call(fsr_instance *inst, const char *method) {
    int gil = py.GILEnsure();
    PyObject *r = call_method(inst->obj, method, NULL);
    int s;
    if (!r) {
        char err[2000];
        py_error_text(err, sizeof err);
        s = fsr_logf(inst, FSR_FATAL, "internal error in the Python slave (%s): %s", method, err);
    } else {
        s = log_reply(inst, py.UnicodeAsUTF8(r));
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
int fsr_resources_path(const char *uri, char *out, size_t n, char *err, size_t en) {
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
    if (!fsr_is_dir(out)) {
        snprintf(err, en, "fmuResourceLocation '%s' -> '%s' is not a folder (%s)", uri, out,
                 strerror(errno ? errno : ENOTDIR));
        return 0;
    }
    return 1;
}

int fsr_is_dir(const char *path) {
    errno = 0;
    int fd = open(path, O_RDONLY | O_DIRECTORY | O_CLOEXEC);
    if (fd < 0) return 0;
    close(fd);
    return 1;
}

/* shortest text that reads back as the same double (like Python's repr) */
const char *fsr_g(double v) {
    static __thread char pool[8][40];
    static __thread int k;
    char *b = pool[k++ & 7];
    for (int prec = 1; prec <= 17; ++prec) {
        snprintf(b, 40, "%.*g", prec, v);
        if (strtod(b, NULL) == v || v != v) break;
    }
    return b;
}


const char *fsr_caus_name(int c) {
    return c == FSR_C_PARAMETER ? "parameter" : c == FSR_C_INPUT ? "input" : "output";
}

/* what a variable accepts, for a refusal message */
void fsr_bound_text(const fsr_instance *inst, unsigned vr, char *out, size_t n) {
    double lo = inst->vmin[vr], hi = inst->vmax[vr];
    if (inst->hint_of[vr] && inst->hint_of[vr][0])
        snprintf(out, n, "one of %s", inst->hint_of[vr]);
    else if (lo == DBL_MIN && isinf(hi))
        snprintf(out, n, "finite and > 0");
    else if (isinf(lo) && isinf(hi))
        snprintf(out, n, "finite");
    else if (isinf(hi))
        snprintf(out, n, "finite and >= %s", fsr_g(lo));
    else if (isinf(lo))
        snprintf(out, n, "finite and <= %s", fsr_g(hi));
    else
        snprintf(out, n, "finite, >= %s and <= %s", fsr_g(lo), fsr_g(hi));
}

/* ------------------------------------------------------------ instance */
static uint64_t g_serial = 0;       /* instances made by this binary (fsr_instance.serial) */

/* layout handed over by FMUInstance.layout() (fmus/runtime.py: LAYOUT -> FSR_L_*) */
static int take_layout(fsr_instance *inst, char *err, size_t n) {
    /* called with the GIL held */
    PyObject *r = call_method(inst->obj, "layout", NULL);
    if (!r) { py_error_text(err, n); return 0; }
    char *buf = NULL;
    Py_ssize_t len = 0;
    uint64_t L[FSR_L_N];
    int ok = py.BytesAsStringAndSize(r, &buf, &len) == 0 && len == (Py_ssize_t)sizeof L;
    if (ok) memcpy(L, buf, sizeof L);
    py.DecRef(r);
    if (!ok) { snprintf(err, n, "bad layout from the Python slave"); return 0; }
    if (L[FSR_L_VERSION] != FSR_VERSION) {
        snprintf(err, n, "layout version %llu, this binary expects %d", (unsigned long long)L[FSR_L_VERSION],
                 FSR_VERSION);
        return 0;
    }
    inst->nvars = (unsigned)L[FSR_L_NVARS];
    inst->x = (double *)(uintptr_t)L[FSR_L_X];
    inst->vtype = (const int32_t *)(uintptr_t)L[FSR_L_TYPE];
    inst->vcaus = (const int32_t *)(uintptr_t)L[FSR_L_CAUS];
    inst->vmin = (const double *)(uintptr_t)L[FSR_L_MIN];
    inst->vmax = (const double *)(uintptr_t)L[FSR_L_MAX];
    inst->work = (double *)(uintptr_t)L[FSR_L_WORK];
    if (inst->work[FSR_H_VERSION] != FSR_VERSION) {
        snprintf(err, n, "work array version %g, this binary expects %d", inst->work[FSR_H_VERSION],
                 FSR_VERSION);
        return 0;
    }
    inst->nwork = (size_t)inst->work[FSR_H_LEN];
    inst->serial = __atomic_add_fetch(&g_serial, 1, __ATOMIC_RELAXED);
    inst->name_of = calloc(inst->nvars, sizeof(char *));
    inst->hint_of = calloc(inst->nvars, sizeof(char *));
    if (!inst->name_of || !inst->hint_of) { snprintf(err, n, "out of memory"); return 0; }
    const char *p = (const char *)(uintptr_t)L[FSR_L_NAMES];
    const char *h = (const char *)(uintptr_t)L[FSR_L_HINTS];
    for (unsigned i = 0; i < inst->nvars; ++i) {
        inst->name_of[i] = p;
        p += strlen(p) + 1;
        inst->hint_of[i] = h;
        h += strlen(h) + 1;
    }
    return 1;
}

/* A new Python instance (boot.instantiate) and its layout. inst->log must be
 * set; the boot's messages are logged; err holds a reason not logged (a Python
 * exception or a bad layout). Returns the worst status (inst->obj NULL on error). */
int fsr_new(fsr_instance *inst, const char *resdir, const char *name, const char *guid, char *err, size_t n) {
    int gil = py.GILEnsure();
    PyObject *dir = py.UnicodeDecodeFSDefault(resdir);
    PyObject *r = dir ? call_method(g_boot, "instantiate", "OssiK", dir, name, guid, g_embedded,
                                      (unsigned long long)(uintptr_t)&fsr_python_step) : NULL;
    if (dir) py.DecRef(dir);
    int s = FSR_OK;
    if (!r) {
        py_error_text(err, n);
        s = FSR_ERROR;
    } else {
        PyObject *msg = py.TupleGetItem(r, 0), *obj = py.TupleGetItem(r, 1);
        s = log_reply(inst, msg ? py.UnicodeAsUTF8(msg) : "E:bad reply from the boot module");
        if (obj && obj != py.None && s < FSR_ERROR) {
            py.IncRef(obj);
            inst->obj = obj;
            if (!take_layout(inst, err, n)) s = FSR_ERROR;
        }
        py.DecRef(r);
    }
    py.GILRelease(gil);
    if (!inst->obj && s < FSR_ERROR) s = FSR_ERROR;
    return s;
}

void fsr_free(fsr_instance *inst) {
    /* a host freeing after its own interpreter shut down: leave the Python object alone */
    if (inst->obj && py.IsInitialized && py.IsInitialized()) {
        int gil = py.GILEnsure();
        PyObject *r = call_method(inst->obj, "free", NULL);
        if (r) py.DecRef(r);
        else { char e[200]; py_error_text(e, sizeof e); }
        py.DecRef(inst->obj);
        py.GILRelease(gil);
    }
    inst->obj = NULL;
    free(inst->name_of);
    free(inst->hint_of);
    inst->name_of = inst->hint_of = NULL;
}

/* ------------------------------------------------------------ FMU states */
/* A state is a copy of the instance's two arrays, the variables x and the work array (time, phase,
 * q, u, inputs and their derivatives, parameters, the packed configuration, vref, the pending
 * impact, the coupling's memory): saving and restoring copy them, no Python and no GIL. Python
 * builds the serialized form from such a copy and checks a deserialized one into one
 * (fmus/runtime.py, InstanceBase.serialize / deserialize). The owner (binary, instance, serial)
 * refuses a state of another instance: the arrays' layout is the instance's own. */
struct fsr_state {
    uint32_t magic;
    const void *binary;             /* &g_serial of the binary that made it */
    const fsr_instance *owner;
    uint64_t serial;                /* the owner's serial (a freed owner's address may be reused) */
    size_t nx, nw;
    double data[];                  /* x (nx), then the work array (nw) */
};
#define STATE_MAGIC 0x66737354u

static fsr_state *state_check(void *handle) {
    fsr_state *st = (fsr_state *)handle;
    return st && st->magic == STATE_MAGIC && st->binary == (const void *)&g_serial ? st : NULL;
}

static int state_owned(const fsr_instance *inst, const fsr_state *st) {
    return st->owner == inst && st->serial == inst->serial && st->nx == inst->nvars && st->nw == inst->nwork;
}

fsr_state *fsr_state_check(const fsr_instance *inst, void *handle) {
    fsr_state *st = state_check(handle);
    return st && state_owned(inst, st) ? st : NULL;
}

fsr_state *fsr_state_of(fsr_instance *inst, const char *call, void *handle) {
    fsr_state *st = state_check(handle);
    if (!st)
        fsr_logf(inst, FSR_ERROR, "%s: not an FMU state of this FMU (NULL or freed handle, or a state of "
                 "another FMU)", call);
    else if (!state_owned(inst, st))
        fsr_logf(inst, FSR_ERROR, "%s: an FMU state of another instance: a state belongs to the instance "
                 "that saved it (serialize it there and deserialize it into this one)", call);
    return st && state_owned(inst, st) ? st : NULL;
}

/* a new state of inst (its contents not yet written) */
static fsr_state *alloc_state(const fsr_instance *inst) {
    fsr_state *st = malloc(sizeof *st + ((size_t)inst->nvars + inst->nwork) * sizeof(double));
    if (!st) return NULL;
    st->magic = STATE_MAGIC;
    st->binary = &g_serial;
    st->owner = inst;
    st->serial = inst->serial;
    st->nx = inst->nvars;
    st->nw = inst->nwork;
    return st;
}

int fsr_state_get(fsr_instance *inst, const char *call, fsr_state **state) {
    fsr_state *st = state_check(*state);
    if (st && !state_owned(inst, st))
        return fsr_logf(inst, FSR_ERROR, "%s: *FMUstate is an FMU state of another instance: pass NULL for a "
                        "new state, or a state this instance saved to overwrite it", call);
    if (!st) {
        st = alloc_state(inst);
        if (!st) return fsr_logf(inst, FSR_ERROR, "%s: out of memory", call);
        *state = st;
    }
    /* FMI: a state of this instance is overwritten in place */
    memcpy(st->data, inst->x, st->nx * sizeof(double));
    memcpy(st->data + st->nx, inst->work, st->nw * sizeof(double));
    return FSR_OK;
}

int fsr_state_set(fsr_instance *inst, fsr_state *st) {
    memcpy(inst->x, st->data, st->nx * sizeof(double));
    memcpy(inst->work, st->data + st->nx, st->nw * sizeof(double));
    return FSR_OK;
}

void fsr_state_free(fsr_state *st) {
    if (!st) return;
    st->magic = 0;
    free(st);
}

int fsr_state_serialize(fsr_instance *inst, const char *call, fsr_state *st, char *out, size_t cap,
                        size_t *size) {
    int gil = py.GILEnsure();
    PyObject *b = py.BytesFromStringAndSize((const char *)st->data,
                                            (Py_ssize_t)((st->nx + st->nw) * sizeof(double)));
    PyObject *r = b ? call_method(inst->obj, "serialize", "O", b) : NULL;
    if (b) py.DecRef(b);
    int s = FSR_ERROR;
    char *buf;
    Py_ssize_t len;
    if (!r) {
        char err[2000];
        py_error_text(err, sizeof err);
        fsr_logf(inst, FSR_ERROR, "%s: %s", call, err);
    } else if (py.BytesAsStringAndSize(r, &buf, &len) == 0) {
        if (size) *size = (size_t)len;
        if (!out) {
            s = FSR_OK;
        } else if ((size_t)len != cap) {
            fsr_logf(inst, FSR_ERROR, "%s: buffer of %zu bytes, the state needs %zu (the serialized state size)",
                     call, cap, (size_t)len);
        } else {
            memcpy(out, buf, cap);
            s = FSR_OK;
        }
    }
    if (r) py.DecRef(r);
    py.GILRelease(gil);
    return s;
}

int fsr_state_deserialize(fsr_instance *inst, const char *call, const char *data, size_t size, fsr_state **out) {
    int gil = py.GILEnsure();
    int s = FSR_ERROR;
    PyObject *b = py.BytesFromStringAndSize(data, (Py_ssize_t)size);
    PyObject *r = b ? call_method(inst->obj, "deserialize", "O", b) : NULL;
    if (b) py.DecRef(b);
    if (!r) {
        char err[2000];
        py_error_text(err, sizeof err);
        fsr_logf(inst, FSR_ERROR, "%s: internal error: %s", call, err);
    } else {
        PyObject *msg = py.TupleGetItem(r, 0), *arrays = py.TupleGetItem(r, 1);
        s = log_reply(inst, msg ? py.UnicodeAsUTF8(msg) : "E:bad reply");
        char *buf = NULL;
        Py_ssize_t len = 0;
        size_t want = ((size_t)inst->nvars + inst->nwork) * sizeof(double);
        if (s < FSR_ERROR && arrays && arrays != py.None && py.BytesAsStringAndSize(arrays, &buf, &len) == 0
            && (size_t)len == want) {
            fsr_state *st = alloc_state(inst);
            if (!st) s = fsr_logf(inst, FSR_ERROR, "%s: out of memory", call);
            else {
                memcpy(st->data, buf, want);
                *out = st;
            }
        } else if (s < FSR_ERROR) {
            if (py.ErrOccurred()) { char e[200]; py_error_text(e, sizeof e); }
            s = fsr_logf(inst, FSR_ERROR, "%s: internal error: no state arrays of %zu bytes from the Python "
                         "slave", call, want);
        }
        py.DecRef(r);
    }
    py.GILRelease(gil);
    return s;
}

/* ------------------------------------------------------------ the communication step (no Python) */
static int native_raised(fsr_instance *inst, const char *call) {
    return fsr_logf(inst, FSR_ERROR, "%s: internal error: the compiled stepper raised an exception at t = %s "
                    "(a state or parameter its code does not handle); the outputs may be partly updated: "
                    "restore a saved FMU state or reset the instance", call, fsr_g(inst->work[FSR_H_TIME]));
}

/* Every step that is refused or cannot complete returns FSR_ERROR with the
 * state unchanged (docs/design.md §5.1): an invalid argument, a step past
 * stopTime, a time that cannot advance, too much work, a state that turned
 * non-finite. Never FSR_DISCARD: nothing is computed over a subinterval, and an
 * importer retrying a discarded step would retry it forever. */
int fsr_step(fsr_instance *inst, double t, double H) {
    double *w = inst->work;
    double now = w[FSR_H_TIME];
#define G fsr_g
#define REFUSED "doStep(t = %s, H = %s) refused, state unchanged at t = %s: "
    if (!(H > 0.0 && isfinite(H)))
        return fsr_logf(inst, FSR_ERROR, REFUSED "communication step size %s rejected: must be finite and > 0",
                        G(t), G(H), G(now), G(H));
    double tol = 1e-9 * (fabs(now) < 1.0 ? 1.0 : fabs(now));
    if (!(fabs(t - now) <= tol))
        return fsr_logf(inst, FSR_ERROR, REFUSED "currentCommunicationPoint = %s is not the slave's time %s "
                        "(restore a saved FMU state to go back in time)", G(t), G(H), G(now), G(t), G(now));
    double t1 = now + H;
    if (!(t1 > now) || !(fabs((t1 - now) - H) <= 1e-6 * H))
        return fsr_logf(inst, FSR_ERROR, REFUSED "the time cannot advance by H at t = %s in double precision "
                        "(t + H - t = %s): the state would move while the time stays; use a larger H or a "
                        "start time nearer 0", G(t), G(H), G(now), G(now), G(t1 - now));
    if (inst->stop_defined && t1 > inst->stop_time + 1e-9 * (fabs(inst->stop_time) < 1.0 ? 1.0 : fabs(inst->stop_time)))
        return fsr_logf(inst, FSR_ERROR, REFUSED "t + H = %s is past the experiment's stopTime = %s "
                        "(fmi2SetupExperiment, fmi3EnterInitializationMode); the last step may end at stopTime", G(t), G(H), G(now), G(t1),
                        G(inst->stop_time));
    double dt = w[FSR_H_DT];
    int exact = w[FSR_H_SCHEME] == FSR_SCHEME_EXACT;
    double count = ceil(H / dt - 1e-9);       /* computed in double: cannot overflow */
    if (!exact && !(count <= FSR_MAX_SUBSTEPS))   /* exact: no internal steps */
        return fsr_logf(inst, FSR_ERROR, REFUSED "it needs ceil(H/dt) = %.6g internal steps of solver.dt = %s, "
                        "more than the limit %.0f (fmu_sync.export.MAX_SUBSTEPS); this step can never complete: use "
                        "a smaller H or a larger solver.dt", G(t), G(H), G(now), count, G(dt),
                        (double)FSR_MAX_SUBSTEPS);
    unsigned errors = fsr_native_errors;
    int32_t rc = fsr_native_step(inst->x, w, now, H);
    if (fsr_native_errors != errors)
        return native_raised(inst, "doStep");
    int warned = FSR_OK;
    switch (rc) {
    case FSR_R_OK:
        break;
    case FSR_R_INADMISSIBLE:   /* the coupling: outputs computed, an input state inside the wall (reason logged) */
        warned = fsr_call(inst, "inadmissible");
        break;
    case FSR_R_EXACT_TAUDOT:
        return fsr_logf(inst, FSR_ERROR, REFUSED "solver.scheme = exact holds the input constant over a "
                        "communication step, but a non-zero input derivative was set "
                        "(fmi2SetRealInputDerivatives before fmi2ExitInitializationMode); set it to 0 or use "
                        "solver.scheme = midpoint or theta", G(t), G(H), G(now));
    case FSR_R_EXACT_EVENTS:
        return fsr_logf(inst, FSR_ERROR, "doStep(t = %s, H = %s) failed and was rolled back, state unchanged "
                        "at t = %s: the exact solver met more than %.0f events in this one step (its work "
                        "guard); use a smaller H", G(t), G(H), G(now), w[FSR_H_MAXEV]);
    case FSR_R_EXACT_STALL:
        return fsr_logf(inst, FSR_ERROR, "doStep(t = %s, H = %s) failed and was rolled back, state unchanged "
                        "at t = %s: the exact solver could not decide a contact (no progress in time)",
                        G(t), G(H), G(now));
    default:
        if (fsr_feedthrough(inst))            /* the coupling FMU: no state of its own, its outputs failed */
            return fsr_logf(inst, FSR_ERROR, "doStep(t = %s, H = %s) failed and was rolled back, state unchanged "
                            "at t = %s: the outputs computed from the current inputs are not finite or a force "
                            "exceeds |tau| <= %s, what the systems accept as input (inputs or gains that overflow "
                            "the coupling forces, or a distance that cannot be computed)",
                            G(t), G(H), G(now), G(w[FSR_H_BOUND]));
        return fsr_logf(inst, FSR_ERROR, "doStep(t = %s, H = %s) failed and was rolled back, state unchanged "
                        "at t = %s: the state became non-finite or left |q|, |u| <= %s with solver.dt = %s "
                        "(a diverging scheme or an overflowing force, e.g. an input or forcing amplitude near "
                        "the float range); this step can never complete with these parameters",
                        G(t), G(H), G(now), G(w[FSR_H_BOUND]), G(dt));
    }
#undef REFUSED
#undef G
    w[FSR_H_TIME] = t1;
    return warned;
}

int fsr_feedthrough(const fsr_instance *inst) {
    return inst->work[FSR_H_FEEDTHROUGH] != 0.0;
}

int fsr_outputs(fsr_instance *inst, const char *call) {
    double *w = inst->work;
    unsigned errors = fsr_native_errors;
    int32_t rc = fsr_native_step(inst->x, w, w[FSR_H_TIME], 0.0);
    if (fsr_native_errors != errors)
        return native_raised(inst, call);
    if (rc == FSR_R_INADMISSIBLE)         /* the coupling: outputs computed, an input state inside the wall */
        return fsr_call(inst, "inadmissible");
    if (rc != 0)
        return fsr_logf(inst, FSR_ERROR, "%s: the outputs computed from the current inputs are not finite "
                        "or a force exceeds |tau| <= %s, what the systems accept as input (or the parameters "
                        "are not a valid set)", call, fsr_g(w[FSR_H_BOUND]));
    return FSR_OK;
}
