/* A plain C FMI 2.0 host that instantiates several FMUs in threads at once (no Python in this
 * process): the test of one interpreter start per process however many fmu-sync binaries are
 * loaded (tests/test_fmu_concurrency.py).
 *
 *   fmu_threads THREADS UNZIPDIR [UNZIPDIR ...]
 *
 * Every FMU's binary is loaded first (dlopen, RTLD_LOCAL, as importers do); then THREADS threads per
 * FMU start together (a barrier) and each runs fmi2Instantiate, SetupExperiment, Enter/Exit
 * InitializationMode, 10 doSteps of 0.01, Terminate, FreeInstance. Prints one line per thread,
 * "thread K fmu F status S" (S the worst status, -1 if fmi2Instantiate returned NULL); the logger
 * (fmu_host.c's) writes to stderr. Exit code 0 when every call of every thread returned fmi2OK.
 */
#define main fmu_host_main      /* fmu_host.c's types, logger, sym, open_binary and uri_of; not its main */
#include "fmu_host.c"
#undef main
#include <limits.h>
#include <pthread.h>

typedef struct {
    char guid[256], uri[8192];
    Instantiate inst;
    FreeInstance freei;
    Setup setup;
    Simple enter, exiti, term;
    DoStep dostep;
} Fmu;

static int load(const char *dir, Fmu *f) {
    char abs[PATH_MAX];
    if (!realpath(dir, abs)) snprintf(abs, sizeof abs, "%s", dir);
    void *lib = open_binary(abs, "linux64", "guid", f->guid, sizeof f->guid);
    if (!lib) return 0;
    f->inst = (Instantiate)sym(lib, "fmi2Instantiate");
    f->freei = (FreeInstance)sym(lib, "fmi2FreeInstance");
    f->setup = (Setup)sym(lib, "fmi2SetupExperiment");
    f->enter = (Simple)sym(lib, "fmi2EnterInitializationMode");
    f->exiti = (Simple)sym(lib, "fmi2ExitInitializationMode");
    f->term = (Simple)sym(lib, "fmi2Terminate");
    f->dostep = (DoStep)sym(lib, "fmi2DoStep");
    uri_of(abs, f->uri, sizeof f->uri);
    return 1;
}

static pthread_barrier_t start;
typedef struct { const Fmu *f; int k, fmu, status; } Job;

static void *run(void *arg) {
    Job *j = arg;
    const Fmu *f = j->f;
    char name[64];
    snprintf(name, sizeof name, "fmu%d-thread%d", j->fmu, j->k);
    Callbacks cb = {logger, calloc, free, NULL, NULL};
    pthread_barrier_wait(&start);
    fmi2Component c = f->inst(name, 1, f->guid, f->uri, &cb, 0, 0);
    if (!c) {
        j->status = -1;
        return NULL;
    }
    int w = f->setup(c, 0, 0.0, 0.0, 0, 0.0);
    int s = f->enter(c);
    if (s > w) w = s;
    if ((s = f->exiti(c)) > w) w = s;
    for (int k = 0; k < 10 && w < 3; ++k)
        if ((s = f->dostep(c, k * 0.01, 0.01, 1)) > w) w = s;
    if ((s = f->term(c)) > w) w = s;
    f->freei(c);
    j->status = w;
    return NULL;
}

int main(int argc, char **argv) {
    if (argc < 3) {
        fprintf(stderr, "usage: fmu_threads THREADS UNZIPDIR [UNZIPDIR ...]\n");
        return 2;
    }
    int T = atoi(argv[1]), nf = argc - 2;
    Fmu *fmus = calloc((size_t)nf, sizeof *fmus);
    for (int i = 0; i < nf; ++i)
        if (!load(argv[2 + i], &fmus[i])) return 5;
    int n = T * nf;
    pthread_t *th = calloc((size_t)n, sizeof *th);
    Job *jobs = calloc((size_t)n, sizeof *jobs);
    pthread_barrier_init(&start, NULL, (unsigned)n);
    for (int i = 0; i < n; ++i) {
        jobs[i] = (Job){&fmus[i % nf], i / nf, i % nf, 0};
        pthread_create(&th[i], NULL, run, &jobs[i]);
    }
    int bad = 0;
    for (int i = 0; i < n; ++i) {
        pthread_join(th[i], NULL);
        printf("thread %d fmu %d status %d\n", jobs[i].k, jobs[i].fmu, jobs[i].status);
        bad |= jobs[i].status != 0;
    }
    return bad ? 1 : 0;
}
