/* A plain C FMI 2.0 / FMI 3.0 co-simulation host for the tests (no Python in this process).
 *
 *   fmu_host UNZIPDIR [options]
 *     --fmi3                   drive it as an FMI 3.0 FMU (fmi3InstantiateCoSimulation, Float64 variables)
 *     --early-return           FMI 3.0: earlyReturnAllowed; a row is written at every early return too
 *     --event-mode             FMI 3.0: eventModeUsed; at eventHandlingNeeded: fmi3EnterEventMode,
 *                              fmi3UpdateDiscreteStates until done, fmi3EnterStepMode, and a second row
 *     --stop T --step H        run setup/enter/exit, doStep 0..T by H, write CSV (default 10, 0.01)
 *     --out FILE.csv           CSV: time and every --var value after each step
 *     --var VR                 Real output value reference to record (repeatable)
 *     --set VR=VALUE           setReal in initialization mode (repeatable)
 *     --input VR=VALUE         setReal before every doStep
 *     --uri URI                fmuResourceLocation (default: file:// + percent-encoded UNZIPDIR/resources)
 *     --guid G                 GUID passed to fmi2Instantiate (default: read from modelDescription.xml)
 *     --type N                 fmuType (default 1 = fmi2CoSimulation)
 *     --cycles N               instantiate / 1 doStep / free N times; print RSS after 20 and after N
 *     --nolog                  loggingOn = false
 *     --timing                 print "first_dostep_monotonic S": CLOCK_MONOTONIC when the first doStep
 *                              returned (the parent compares it with its clock before starting us)
 *
 * Prints "instantiate NULL" and exits 3 if fmi2Instantiate fails; "status CALL S"
 * for any call that does not return fmi2OK; the logger writes to stderr as
 * "LOG status category: message". Exit code 0 when every call returned fmi2OK.
 */
#define _GNU_SOURCE
#include <dlfcn.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

typedef void *fmi2Component;
typedef unsigned int fmi2ValueReference;
typedef enum { fmi2OK, fmi2Warning, fmi2Discard, fmi2Error, fmi2Fatal, fmi2Pending } fmi2Status;
typedef void (*Logger)(void *, const char *, fmi2Status, const char *, const char *, ...);
typedef struct {
    Logger logger;
    void *(*allocateMemory)(size_t, size_t);
    void (*freeMemory)(void *);
    void (*stepFinished)(void *, fmi2Status);
    void *componentEnvironment;
} Callbacks;

typedef fmi2Component (*Instantiate)(const char *, int, const char *, const char *, const Callbacks *, int, int);
typedef void (*FreeInstance)(fmi2Component);
typedef fmi2Status (*Setup)(fmi2Component, int, double, double, int, double);
typedef fmi2Status (*Simple)(fmi2Component);
typedef fmi2Status (*SetReal)(fmi2Component, const fmi2ValueReference *, size_t, const double *);
typedef fmi2Status (*GetReal)(fmi2Component, const fmi2ValueReference *, size_t, double *);
typedef fmi2Status (*DoStep)(fmi2Component, double, double, int);

#include "../../fmus/c/fmi3_abi.h"

static void logger3(fmi3InstanceEnvironment env, fmi3Status s, fmi3String cat, fmi3String msg) {
    (void)env;
    fprintf(stderr, "LOG %d %s: %s\n", (int)s, cat ? cat : "", msg ? msg : "");
}

static void logger(void *env, const char *name, fmi2Status s, const char *cat, const char *msg, ...) {
    (void)env; (void)name;
    char buf[8192];
    va_list ap;
    va_start(ap, msg);
    vsnprintf(buf, sizeof buf, msg, ap);   /* the message is a printf format */
    va_end(ap);
    fprintf(stderr, "LOG %d %s: %s\n", (int)s, cat ? cat : "", buf);
}

static long rss_kb(void) {
    FILE *f = fopen("/proc/self/statm", "r");
    long pages = 0, res = 0;
    if (f) {
        if (fscanf(f, "%ld %ld", &pages, &res) != 2) res = 0;
        fclose(f);
    }
    return res * 4;
}

static void *sym(void *lib, const char *name) {
    void *p = dlsym(lib, name);
    if (!p) {
        printf("missing symbol %s\n", name);
        exit(4);
    }
    return p;
}

static int worst = 0;
static void check(const char *call, fmi2Status s) {
    if (s != fmi2OK) {
        printf("status %s %d\n", call, (int)s);
        fflush(stdout);
    }
    if ((int)s > worst) worst = (int)s;
}

static void read_attr(const char *xml, const char *attr, char *out, size_t n) {
    FILE *f = fopen(xml, "r");
    out[0] = '\0';
    if (!f) return;
    static char buf[1 << 20];
    size_t len = fread(buf, 1, sizeof buf - 1, f);
    buf[len] = '\0';
    fclose(f);
    char key[64];
    snprintf(key, sizeof key, "%s=\"", attr);
    char *p = strstr(buf, key);
    if (!p) return;
    p += strlen(key);
    char *e = strchr(p, '"');
    if (!e) return;
    snprintf(out, n, "%.*s", (int)(e - p), p);
}

static void uri_of(const char *dir, char *out, size_t n) {
    static const char *hex = "0123456789ABCDEF";
    size_t j = snprintf(out, n, "file://");
    for (const unsigned char *p = (const unsigned char *)dir; *p && j + 4 < n; ++p) {
        int keep = (*p >= 'a' && *p <= 'z') || (*p >= 'A' && *p <= 'Z') || (*p >= '0' && *p <= '9') ||
                   strchr("-._~/", *p);
        if (keep) out[j++] = (char)*p;
        else {
            out[j++] = '%';
            out[j++] = hex[*p >> 4];
            out[j++] = hex[*p & 15];
        }
    }
    snprintf(out + j, n - j, "/resources");
}

/* dlopen the FMU's binaries/<platform>/<modelIdentifier>.so and read the identity attribute
 * id_attr ("guid" or "instantiationToken") of its modelDescription.xml into id; NULL (the reason
 * printed) if it cannot be loaded */
static void *open_binary(const char *dir, const char *platform, const char *id_attr, char *id, size_t n) {
    char path[4096], ident[256];
    snprintf(path, sizeof path, "%s/modelDescription.xml", dir);
    read_attr(path, "modelIdentifier", ident, sizeof ident);
    read_attr(path, id_attr, id, n);
    snprintf(path, sizeof path, "%s/binaries/%s/%s.so", dir, platform, ident);
    void *lib = dlopen(path, RTLD_NOW | RTLD_LOCAL);
    if (!lib) printf("dlopen failed: %s\n", dlerror());
    return lib;
}

static void write_row(FILE *csv, double t, const double *vals, int n) {
    if (!csv) return;
    fprintf(csv, "%.17g", t);
    for (int i = 0; i < n; ++i) fprintf(csv, ",%.17g", vals[i]);
    fprintf(csv, "\n");
}

/* FMI 3.0: instantiate, initialize (the --set values), step 0..stop by H with early
 * returns and event mode as asked, write time and the --var values; the exit code
 * as for FMI 2.0. */
static int run_fmi3(const char *dir, double stop, double H, const char *out, const unsigned *vars, int nvars,
                    const unsigned *setv, const double *setx, int nset, int early, int event, int logging) {
    char token[256], res[4200];
    void *lib = open_binary(dir, "x86_64-linux", "instantiationToken", token, sizeof token);
    if (!lib) return 5;
    fmi3InstantiateCoSimulationTYPE *inst = (fmi3InstantiateCoSimulationTYPE *)sym(lib, "fmi3InstantiateCoSimulation");
    fmi3FreeInstanceTYPE *freei = (fmi3FreeInstanceTYPE *)sym(lib, "fmi3FreeInstance");
    fmi3EnterInitializationModeTYPE *enter = (fmi3EnterInitializationModeTYPE *)sym(lib, "fmi3EnterInitializationMode");
    fmi3InstanceCallTYPE *exiti = (fmi3InstanceCallTYPE *)sym(lib, "fmi3ExitInitializationMode");
    fmi3InstanceCallTYPE *enter_event = (fmi3InstanceCallTYPE *)sym(lib, "fmi3EnterEventMode");
    fmi3InstanceCallTYPE *enter_step = (fmi3InstanceCallTYPE *)sym(lib, "fmi3EnterStepMode");
    fmi3InstanceCallTYPE *term = (fmi3InstanceCallTYPE *)sym(lib, "fmi3Terminate");
    fmi3SetFloat64TYPE *setr = (fmi3SetFloat64TYPE *)sym(lib, "fmi3SetFloat64");
    fmi3GetFloat64TYPE *getr = (fmi3GetFloat64TYPE *)sym(lib, "fmi3GetFloat64");
    fmi3UpdateDiscreteStatesTYPE *update = (fmi3UpdateDiscreteStatesTYPE *)sym(lib, "fmi3UpdateDiscreteStates");
    fmi3DoStepTYPE *dostep = (fmi3DoStepTYPE *)sym(lib, "fmi3DoStep");
    snprintf(res, sizeof res, "%s/resources/", dir);
    fmi3Instance c = inst("host", token, res, false, logging, event, early, NULL, 0, NULL, logger3, NULL);
    if (!c) {
        printf("instantiate NULL\n");
        return 3;
    }
    FILE *csv = out ? fopen(out, "w") : NULL;
    double vals[64];
    check("fmi3EnterInitializationMode", (fmi2Status)enter(c, false, 0.0, 0.0, true, stop));
    for (int i = 0; i < nset; ++i) check("fmi3SetFloat64", (fmi2Status)setr(c, &setv[i], 1, &setx[i], 1));
    check("fmi3ExitInitializationMode", (fmi2Status)exiti(c));
    if (event) {
        bool more = true, stopit, b1, b2, b3;
        double te;
        while (more && worst < fmi2Error) check("fmi3UpdateDiscreteStates", (fmi2Status)update(c, &more, &stopit, &b1, &b2, &b3, &te));
        check("fmi3EnterStepMode", (fmi2Status)enter_step(c));
    }
    if (csv) {
        fprintf(csv, "time");
        for (int i = 0; i < nvars; ++i) fprintf(csv, ",vr%u", vars[i]);
        fprintf(csv, "\n");
    }
    long nsteps = (long)(stop / H + 0.5), k = 0;
    double t = 0.0;
    while (worst < fmi2Error) {
        if (nvars) check("fmi3GetFloat64", (fmi2Status)getr(c, vars, (size_t)nvars, vals, (size_t)nvars));
        write_row(csv, t, vals, nvars);
        if (k == nsteps) break;
        bool need = false, stopit = false, er = false;
        double next = (k + 1) * H, last = t;
        check("fmi3DoStep", (fmi2Status)dostep(c, t, next - t, true, &need, &stopit, &er, &last));
        if (worst >= fmi2Error) break;
        if (er && !early) { printf("early return without earlyReturnAllowed\n"); worst = 9; break; }
        t = er ? last : next;
        if (!er) ++k;
        if (need && event) {
            if (nvars) check("fmi3GetFloat64", (fmi2Status)getr(c, vars, (size_t)nvars, vals, (size_t)nvars));
            write_row(csv, t, vals, nvars);
            check("fmi3EnterEventMode", (fmi2Status)enter_event(c));
            bool more = true, b1, b2, b3;
            double te;
            while (more && worst < fmi2Error) check("fmi3UpdateDiscreteStates", (fmi2Status)update(c, &more, &stopit, &b1, &b2, &b3, &te));
            check("fmi3EnterStepMode", (fmi2Status)enter_step(c));
        }
    }
    if (csv) fclose(csv);
    check("fmi3Terminate", (fmi2Status)term(c));
    freei(c);
    return worst > fmi2OK ? 1 : 0;
}

int main(int argc, char **argv) {
    if (argc < 2) {
        fprintf(stderr, "usage: fmu_host UNZIPDIR [options]\n");
        return 2;
    }
    const char *dir = argv[1];
    double stop = 10.0, H = 0.01;
    const char *out = NULL, *uri_opt = NULL, *guid_opt = NULL;
    int type = 1, cycles = 0, logging = 1, input_first = 0, fmi3 = 0, early = 0, event = 0, timing = 0;
    unsigned vars[64], setv[64], inv[64];
    double setx[64], inx[64];
    int nvars = 0, nset = 0, nin = 0;
    for (int i = 2; i < argc; ++i) {
        const char *a = argv[i];
        const char *v = i + 1 < argc ? argv[i + 1] : "";
        if (!strcmp(a, "--stop")) stop = atof(v), ++i;
        else if (!strcmp(a, "--step")) H = atof(v), ++i;
        else if (!strcmp(a, "--out")) out = v, ++i;
        else if (!strcmp(a, "--var")) vars[nvars++] = (unsigned)strtoul(v, NULL, 10), ++i;
        else if (!strcmp(a, "--set")) { setv[nset] = (unsigned)strtoul(v, NULL, 10); setx[nset++] = atof(strchr(v, '=') + 1); ++i; }
        else if (!strcmp(a, "--input")) { inv[nin] = (unsigned)strtoul(v, NULL, 10); inx[nin++] = atof(strchr(v, '=') + 1); ++i; }
        else if (!strcmp(a, "--uri")) uri_opt = v, ++i;
        else if (!strcmp(a, "--guid")) guid_opt = v, ++i;
        else if (!strcmp(a, "--type")) type = atoi(v), ++i;
        else if (!strcmp(a, "--cycles")) cycles = atoi(v), ++i;
        else if (!strcmp(a, "--nolog")) logging = 0;
        else if (!strcmp(a, "--timing")) timing = 1;
        else if (!strcmp(a, "--input-first")) input_first = 1;   /* set the inputs before the first read too */
        else if (!strcmp(a, "--fmi3")) fmi3 = 1;
        else if (!strcmp(a, "--early-return")) early = 1;
        else if (!strcmp(a, "--event-mode")) event = 1;
        else { fprintf(stderr, "unknown option %s\n", a); return 2; }
    }
    if (fmi3) return run_fmi3(dir, stop, H, out, vars, nvars, setv, setx, nset, early, event, logging);
    char guid[256], uri[8192];
    void *lib = open_binary(dir, "linux64", "guid", guid, sizeof guid);
    if (!lib) return 5;
    Instantiate inst = (Instantiate)sym(lib, "fmi2Instantiate");
    FreeInstance freei = (FreeInstance)sym(lib, "fmi2FreeInstance");
    Setup setup = (Setup)sym(lib, "fmi2SetupExperiment");
    Simple enter = (Simple)sym(lib, "fmi2EnterInitializationMode");
    Simple exiti = (Simple)sym(lib, "fmi2ExitInitializationMode");
    Simple term = (Simple)sym(lib, "fmi2Terminate");
    SetReal setr = (SetReal)sym(lib, "fmi2SetReal");
    GetReal getr = (GetReal)sym(lib, "fmi2GetReal");
    DoStep dostep = (DoStep)sym(lib, "fmi2DoStep");
    if (uri_opt) snprintf(uri, sizeof uri, "%s", uri_opt);
    else uri_of(dir, uri, sizeof uri);
    Callbacks cb = {logger, calloc, free, NULL, NULL};

    if (cycles > 0) {
        long rss20 = 0;
        for (int k = 0; k < cycles; ++k) {
            fmi2Component c = inst("cycle", type, guid_opt ? guid_opt : guid, uri, &cb, 0, logging);
            if (!c) { printf("instantiate NULL\n"); return 3; }
            check("setup", setup(c, 0, 0.0, 0.0, 0, 0.0));
            check("enter", enter(c));
            check("exit", exiti(c));
            check("doStep", dostep(c, 0.0, H, 1));
            unsigned bad = 4294967295u;
            double x;
            if (getr(c, &bad, 1, &x) != fmi2Error) worst = 9;   /* logs a message each cycle */
            check("terminate", term(c));
            freei(c);
            if (k + 1 == 20) rss20 = rss_kb();
        }
        printf("rss_kb_after_20 %ld\nrss_kb_after_%d %ld\n", rss20, cycles, rss_kb());
        return worst > fmi2OK ? 1 : 0;
    }

    fmi2Component c = inst("host", type, guid_opt ? guid_opt : guid, uri, &cb, 0, logging);
    if (!c) {
        printf("instantiate NULL\n");
        return 3;
    }
    FILE *csv = out ? fopen(out, "w") : NULL;
    check("fmi2SetupExperiment", setup(c, 0, 0.0, 0.0, 1, stop));
    check("fmi2EnterInitializationMode", enter(c));
    for (int i = 0; i < nset; ++i) check("fmi2SetReal", setr(c, &setv[i], 1, &setx[i]));
    check("fmi2ExitInitializationMode", exiti(c));
    double vals[64];
    if (csv) {
        fprintf(csv, "time");
        for (int i = 0; i < nvars; ++i) fprintf(csv, ",vr%u", vars[i]);
        fprintf(csv, "\n");
    }
    long nsteps = (long)(stop / H + 0.5);
    for (long k = 0; k <= nsteps; ++k) {
        double t = k * H;
        if (k > 0) {
            for (int i = 0; i < nin; ++i) check("fmi2SetReal", setr(c, &inv[i], 1, &inx[i]));
            fmi2Status s = dostep(c, (k - 1) * H, H, 1);
            if (timing && k == 1) {
                struct timespec ts;
                clock_gettime(CLOCK_MONOTONIC, &ts);
                printf("first_dostep_monotonic %.9f\n", ts.tv_sec + 1e-9 * ts.tv_nsec);
            }
            check("fmi2DoStep", s);
            if (s > fmi2Warning) break;
        }
        if (k == 0 && input_first)
            for (int i = 0; i < nin; ++i) check("fmi2SetReal", setr(c, &inv[i], 1, &inx[i]));
        if (nvars) check("fmi2GetReal", getr(c, vars, (size_t)nvars, vals));
        write_row(csv, t, vals, nvars);
    }
    if (csv) fclose(csv);
    check("fmi2Terminate", term(c));
    freei(c);
    return worst > fmi2OK ? 1 : 0;
}
