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

#include "../c/fmi2_test_stub.h"      /* EXPORT, the FMI 2.0 types and the calls that do nothing */

typedef struct { double x, v, k, f, t; } Spring;

FMI2_TEST_CALLS(Spring)

EXPORT fmi2Component fmi2Instantiate(fmi2String name, fmi2Type type, fmi2String guid, fmi2String res,
                                     const void *functions, fmi2Boolean visible, fmi2Boolean logging) {
    (void)name; (void)guid; (void)res; (void)functions; (void)visible; (void)logging;
    if (type != fmi2CoSimulation) return NULL;
    Spring *s = calloc(1, sizeof(Spring));
    if (s) { s->x = 1.0; s->k = 4.0; }
    return s;
}
EXPORT fmi2Status fmi2ExitInitializationMode(fmi2Component c) { (void)c; return fmi2OK; }
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
FMI2_TEST_REFUSALS
REFUSE(fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Integer v[]))
REFUSE(fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Integer v[]))
REFUSE(fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *s))
REFUSE(fmi2SetFMUstate(fmi2Component c, fmi2FMUstate s))
REFUSE(fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *s))
REFUSE(fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                                   const fmi2Integer order[], const fmi2Real value[]))
