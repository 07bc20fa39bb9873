/* A minimal FMI 2.0 co-simulation FMU that is NOT an fmu-sync model (test fixture).
 *
 *   x' = v,  v' = -k x + f     (symplectic Euler, one internal step per doStep)
 *
 * Variables (value references): 0 x (output), 1 v (output), 2 k (parameter),
 * 3 f (input). Written for the fmu-sync tests; the FMI 2.0 types come from
 * fmus/c/fmi2_abi.h (the standard's headers are not required).
 */
#include <stdlib.h>
#include <string.h>

#include "../../fmus/c/fmi2_abi.h"   /* the FMI 2.0 types (not our model code) */

#define EXPORT __attribute__((visibility("default")))

typedef struct { double x, v, k, f, t; } Spring;

EXPORT const char *fmi2GetTypesPlatform(void) { return "default"; }
EXPORT const char *fmi2GetVersion(void) { return "2.0"; }

EXPORT fmi2Component fmi2Instantiate(fmi2String name, fmi2Type type, fmi2String guid, fmi2String res,
                                     const void *functions, fmi2Boolean visible, fmi2Boolean logging) {
    (void)name; (void)guid; (void)res; (void)functions; (void)visible; (void)logging;
    if (type != fmi2CoSimulation) return NULL;
    Spring *s = calloc(1, sizeof(Spring));
    if (s) { s->x = 1.0; s->k = 4.0; }
    return s;
}
EXPORT void fmi2FreeInstance(fmi2Component c) { free(c); }
EXPORT fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean on, size_t n, const fmi2String cats[]) {
    (void)c; (void)on; (void)n; (void)cats; return fmi2OK;
}
EXPORT fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean tol_on, fmi2Real tol, fmi2Real t0,
                                      fmi2Boolean stop_on, fmi2Real stop) {
    (void)tol_on; (void)tol; (void)stop_on; (void)stop; ((Spring *)c)->t = t0; return fmi2OK;
}
EXPORT fmi2Status fmi2EnterInitializationMode(fmi2Component c) { (void)c; return fmi2OK; }
EXPORT fmi2Status fmi2ExitInitializationMode(fmi2Component c) { (void)c; return fmi2OK; }
EXPORT fmi2Status fmi2Terminate(fmi2Component c) { (void)c; return fmi2OK; }
EXPORT fmi2Status fmi2Reset(fmi2Component c) {
    Spring *s = c; memset(s, 0, sizeof *s); s->x = 1.0; s->k = 4.0; return fmi2OK;
}

static double *slot(Spring *s, fmi2ValueReference vr) {
    switch (vr) { case 0: return &s->x; case 1: return &s->v; case 2: return &s->k; case 3: return &s->f; }
    return NULL;
}
EXPORT fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Real value[]) {
    for (size_t i = 0; i < n; i++) { double *p = slot(c, vr[i]); if (!p) return fmi2Error; value[i] = *p; }
    return fmi2OK;
}
EXPORT fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Real value[]) {
    for (size_t i = 0; i < n; i++) { double *p = slot(c, vr[i]); if (!p) return fmi2Error; *p = value[i]; }
    return fmi2OK;
}
EXPORT fmi2Status fmi2DoStep(fmi2Component c, fmi2Real t, fmi2Real h, fmi2Boolean noSetPrior) {
    Spring *s = c; (void)noSetPrior;
    s->v += h * (-s->k * s->x + s->f);
    s->x += h * s->v;
    s->t = t + h;
    return fmi2OK;
}

/* Everything else this FMU does not support. */
#define REFUSE(decl) EXPORT fmi2Status decl { return fmi2Error; }
REFUSE(fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Integer v[]))
REFUSE(fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Boolean v[]))
REFUSE(fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2String v[]))
REFUSE(fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Integer v[]))
REFUSE(fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Boolean v[]))
REFUSE(fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2String v[]))
REFUSE(fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *s))
REFUSE(fmi2SetFMUstate(fmi2Component c, fmi2FMUstate s))
REFUSE(fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *s))
REFUSE(fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate s, size_t *size))
REFUSE(fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate s, fmi2Byte b[], size_t size))
REFUSE(fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte b[], size_t size, fmi2FMUstate *s))
REFUSE(fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference a[], size_t na,
                                    const fmi2ValueReference b[], size_t nb, const fmi2Real dv[], fmi2Real df[]))
REFUSE(fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                                   const fmi2Integer order[], const fmi2Real value[]))
REFUSE(fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                                    const fmi2Integer order[], fmi2Real value[]))
REFUSE(fmi2CancelStep(fmi2Component c))
REFUSE(fmi2GetStatus(fmi2Component c, const fmi2StatusKind s, fmi2Status *value))
REFUSE(fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind s, fmi2Real *value))
REFUSE(fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind s, fmi2Integer *value))
REFUSE(fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind s, fmi2Boolean *value))
REFUSE(fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind s, fmi2String *value))
