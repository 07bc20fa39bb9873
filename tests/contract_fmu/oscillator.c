/* A C FMI 2.0 co-simulation FMU with the fmu-sync contract's variables (test fixture).
 *
 * It is not our binary: a plain C impact oscillator (symplectic Euler over solver.dt,
 * the wall at q = 0 reflects u -> -e u), written for the master's tests. The value
 * references and start values come from "contract_vars.h", which the test generates
 * from fmu_sync.fmus.contract (VR_<name>, NV, START[]). Failure switch (Integer
 * parameters): fail_call (1 doStep, 2 setReal, 3 getReal, 4 getInteger, 5 getFMUstate,
 * 6 setRealInputDerivatives) returns fail_status once the instance has made fail_step
 * doSteps (doStep: the fail_step-th doStep), with the reason in the log.
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "../c/fmi2_test_stub.h"      /* EXPORT, the FMI 2.0 types and the calls that do nothing */
#include "contract_vars.h"
enum { F_DOSTEP = 1, F_SETREAL, F_GETREAL, F_GETINT, F_GETSTATE, F_SETDER };

typedef struct {
    double r[NV];        /* Real variables by value reference */
    int iv[NV];          /* Integer variables by value reference */
    double der, t;       /* input derivative of tau, time */
    int steps;
    fmi2CallbackFunctions cb;
    char name[64];
} Osc;

FMI2_TEST_CALLS(Osc)

static fmi2Status fail(Osc *s, int call, const char *what) {
    if (s->iv[VR_fail_call] != call || s->steps != s->iv[VR_fail_step] - (call == F_DOSTEP)) return fmi2OK;
    int st = s->iv[VR_fail_status];
    char msg[160];
    snprintf(msg, sizeof msg, "%s: injected failure after %d doSteps (fail_call = %d)", what, s->steps, call);
    if (s->cb.logger) s->cb.logger(s->cb.componentEnvironment, s->name, (fmi2Status)st, "logStatusError", msg);
    return (fmi2Status)st;
}


EXPORT fmi2Component fmi2Instantiate(fmi2String name, fmi2Type type, fmi2String guid, fmi2String res,
                                     const fmi2CallbackFunctions *functions, fmi2Boolean visible,
                                     fmi2Boolean logging) {
    (void)guid; (void)res; (void)visible; (void)logging;
    if (type != fmi2CoSimulation) return NULL;
    Osc *s = calloc(1, sizeof(Osc));
    if (!s) return NULL;
    for (int k = 0; k < NV; k++) { s->r[k] = START[k]; s->iv[k] = (int)START[k]; }
    if (functions) s->cb = *functions;
    snprintf(s->name, sizeof s->name, "%s", name ? name : "");
    return s;
}
EXPORT fmi2Status fmi2ExitInitializationMode(fmi2Component c) {
    Osc *s = c; s->r[VR_q] = s->r[VR_q_start]; s->r[VR_u] = s->r[VR_u_start]; return fmi2OK;
}
EXPORT fmi2Status fmi2Reset(fmi2Component c) { (void)c; return fmi2Error; }

EXPORT fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Real value[]) {
    Osc *s = c; fmi2Status st = fail(s, F_GETREAL, "fmi2GetReal");
    if (st > fmi2Warning) return st;
    for (size_t k = 0; k < n; k++) { if (vr[k] >= NV) return fmi2Error; value[k] = s->r[vr[k]]; }
    return fmi2OK;
}
EXPORT fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Real value[]) {
    Osc *s = c; fmi2Status st = fail(s, F_SETREAL, "fmi2SetReal");
    if (st > fmi2Warning) return st;
    for (size_t k = 0; k < n; k++) {
        if (vr[k] >= NV) return fmi2Error;
        s->r[vr[k]] = value[k];
        if (vr[k] == VR_tau) s->der = 0.0;   /* setting an input resets its derivative */
    }
    return fmi2OK;
}
EXPORT fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Integer v[]) {
    Osc *s = c; fmi2Status st = fail(s, F_GETINT, "fmi2GetInteger");
    if (st > fmi2Warning) return st;
    for (size_t k = 0; k < n; k++) { if (vr[k] >= NV) return fmi2Error; v[k] = s->iv[vr[k]]; }
    return fmi2OK;
}
EXPORT fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Integer v[]) {
    Osc *s = c;
    for (size_t k = 0; k < n; k++) { if (vr[k] >= NV) return fmi2Error; s->iv[vr[k]] = v[k]; }
    return fmi2OK;
}
EXPORT fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                                              const fmi2Integer order[], const fmi2Real value[]) {
    Osc *s = c; fmi2Status st = fail(s, F_SETDER, "fmi2SetRealInputDerivatives");
    if (st > fmi2Warning) return st;
    for (size_t k = 0; k < n; k++) { if (vr[k] != VR_tau || order[k] != 1) return fmi2Error; s->der = value[k]; }
    return fmi2OK;
}

EXPORT fmi2Status fmi2DoStep(fmi2Component c, fmi2Real t, fmi2Real h, fmi2Boolean noSetPrior) {
    Osc *s = c; (void)noSetPrior;
    fmi2Status st = fail(s, F_DOSTEP, "fmi2DoStep");
    if (st > fmi2Warning) return st;
    double *r = s->r;
    int count = (int)ceil(h / r[VR_solver_dt] - 1e-9);
    if (count < 1) count = 1;
    double ds = h / count, q = r[VR_q], u = r[VR_u];
    for (int k = 0; k < count; k++) {
        double sk = t + k * ds, tau = r[VR_tau] + s->der * (sk + 0.5 * ds - t);
        double a = (-r[VR_k] * q - r[VR_c] * u + r[VR_f0] + r[VR_F] * cos(r[VR_Omega] * sk + r[VR_phi]) + tau) / r[VR_m];
        u += ds * a;
        q += ds * u;
        if (q < 0.0) { q = 0.0; u = -r[VR_e] * u; s->iv[VR_impacts] += 1; }
    }
    r[VR_q] = q; r[VR_u] = u; r[VR_gap] = q;
    s->t = t + h;
    s->steps += 1;
    return fmi2OK;
}

EXPORT fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *state) {
    Osc *s = c; fmi2Status st = fail(s, F_GETSTATE, "fmi2GetFMUstate");
    if (st > fmi2Warning) return st;
    if (!*state) *state = malloc(sizeof(Osc));
    memcpy(*state, s, sizeof(Osc));
    return fmi2OK;
}
EXPORT fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate state) {
    Osc *s = c; int steps = s->steps;
    memcpy(s, state, sizeof(Osc));
    s->steps = steps;   /* the failure switch counts every doStep made */
    return fmi2OK;
}
EXPORT fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *state) {
    (void)c; free(*state); *state = NULL; return fmi2OK;
}

FMI2_TEST_REFUSALS
