/* A minimal FMI 2.0 co-simulation FMU: the cost baseline of fmu_sync.benchmarks.fmu_cost.
 *
 * The same interface as the benchmarked FMU (NVARS Real/Integer slots indexed by
 * value reference, one input TAU, outputs Q and U), a trivial step
 * (u += H tau, q += H u), no checks: what an FMI call costs when the model does
 * nothing. Compiled by the benchmark with -DNVARS=.. -DVR_TAU=.. -DVR_Q=.. -DVR_U=.. */
#include <stdlib.h>
#include <string.h>

typedef void *C;
typedef unsigned int VR;
typedef int St;
typedef struct { double x[NVARS]; } Inst;
#define EXPORT __attribute__((visibility("default")))

EXPORT const char *fmi2GetTypesPlatform(void) { return "default"; }
EXPORT const char *fmi2GetVersion(void) { return "2.0"; }
EXPORT C fmi2Instantiate(const char *n, int t, const char *g, const char *r, const void *cb, int v, int l) {
    (void)n; (void)t; (void)g; (void)r; (void)cb; (void)v; (void)l;
    Inst *c = calloc(1, sizeof(Inst));
    c->x[VR_Q] = 1.0;
    return c;
}
EXPORT void fmi2FreeInstance(C c) { free(c); }
EXPORT St fmi2SetDebugLogging(C c, int l, size_t n, const char *const k[]) { (void)c; (void)l; (void)n; (void)k; return 0; }
EXPORT St fmi2SetupExperiment(C c, int a, double b, double d, int e, double f) { (void)c; (void)a; (void)b; (void)d; (void)e; (void)f; return 0; }
EXPORT St fmi2EnterInitializationMode(C c) { (void)c; return 0; }
EXPORT St fmi2ExitInitializationMode(C c) { (void)c; return 0; }
EXPORT St fmi2Terminate(C c) { (void)c; return 0; }
EXPORT St fmi2Reset(C c) { (void)c; return 0; }
EXPORT St fmi2GetReal(C c, const VR vr[], size_t n, double v[]) {
    Inst *i = c;
    for (size_t k = 0; k < n; ++k) v[k] = i->x[vr[k]];
    return 0;
}
EXPORT St fmi2GetInteger(C c, const VR vr[], size_t n, int v[]) {
    Inst *i = c;
    for (size_t k = 0; k < n; ++k) v[k] = (int)i->x[vr[k]];
    return 0;
}
EXPORT St fmi2GetBoolean(C c, const VR vr[], size_t n, int v[]) { (void)c; (void)vr; (void)n; (void)v; return 3; }
EXPORT St fmi2GetString(C c, const VR vr[], size_t n, const char *v[]) { (void)c; (void)vr; (void)n; (void)v; return 3; }
EXPORT St fmi2SetReal(C c, const VR vr[], size_t n, const double v[]) {
    Inst *i = c;
    for (size_t k = 0; k < n; ++k) i->x[vr[k]] = v[k];
    return 0;
}
EXPORT St fmi2SetInteger(C c, const VR vr[], size_t n, const int v[]) {
    Inst *i = c;
    for (size_t k = 0; k < n; ++k) i->x[vr[k]] = v[k];
    return 0;
}
EXPORT St fmi2SetBoolean(C c, const VR vr[], size_t n, const int v[]) { (void)c; (void)vr; (void)n; (void)v; return 3; }
EXPORT St fmi2SetString(C c, const VR vr[], size_t n, const char *const v[]) { (void)c; (void)vr; (void)n; (void)v; return 3; }
EXPORT St fmi2GetFMUstate(C c, void **s) { (void)c; (void)s; return 3; }
EXPORT St fmi2SetFMUstate(C c, void *s) { (void)c; (void)s; return 3; }
EXPORT St fmi2FreeFMUstate(C c, void **s) { (void)c; (void)s; return 3; }
EXPORT St fmi2SerializedFMUstateSize(C c, void *s, size_t *n) { (void)c; (void)s; (void)n; return 3; }
EXPORT St fmi2SerializeFMUstate(C c, void *s, char b[], size_t n) { (void)c; (void)s; (void)b; (void)n; return 3; }
EXPORT St fmi2DeSerializeFMUstate(C c, const char b[], size_t n, void **s) { (void)c; (void)b; (void)n; (void)s; return 3; }
EXPORT St fmi2GetDirectionalDerivative(C c, const VR a[], size_t b, const VR d[], size_t e, const double f[], double g[]) { (void)c; (void)a; (void)b; (void)d; (void)e; (void)f; (void)g; return 3; }
EXPORT St fmi2SetRealInputDerivatives(C c, const VR vr[], size_t n, const int o[], const double v[]) { (void)c; (void)vr; (void)n; (void)o; (void)v; return 3; }
EXPORT St fmi2GetRealOutputDerivatives(C c, const VR vr[], size_t n, const int o[], double v[]) { (void)c; (void)vr; (void)n; (void)o; (void)v; return 3; }
EXPORT St fmi2DoStep(C c, double t, double H, int nsp) {
    Inst *i = c;
    (void)t; (void)nsp;
    i->x[VR_U] += H * i->x[VR_TAU];
    i->x[VR_Q] += H * i->x[VR_U];
    return 0;
}
EXPORT St fmi2CancelStep(C c) { (void)c; return 3; }
EXPORT St fmi2GetStatus(C c, int k, int *v) { (void)c; (void)k; (void)v; return 3; }
EXPORT St fmi2GetRealStatus(C c, int k, double *v) { (void)c; (void)k; *v = 0.0; return 0; }
EXPORT St fmi2GetIntegerStatus(C c, int k, int *v) { (void)c; (void)k; (void)v; return 3; }
EXPORT St fmi2GetBooleanStatus(C c, int k, int *v) { (void)c; (void)k; *v = 0; return 0; }
EXPORT St fmi2GetStringStatus(C c, int k, const char **v) { (void)c; (void)k; (void)v; return 3; }
