/* What the two hand-written FMI 2.0 test FMUs share (tests/contract_fmu/oscillator.c,
 * tests/foreign_fmu/spring.c): EXPORT and the calls they accept without doing anything.
 * FMI2_TEST_CALLS(TYPE): TYPE is the instance struct, with a double t (the start time). */
#ifndef FMI2_TEST_STUB_H
#define FMI2_TEST_STUB_H
#include <stdlib.h>

#include "../../fmus/c/fmi2_abi.h"   /* the FMI 2.0 types (not our model code) */

#define EXPORT __attribute__((visibility("default")))

#define FMI2_TEST_CALLS(TYPE)                                                                                   \
    EXPORT const char *fmi2GetTypesPlatform(void) { return "default"; }                                       \
    EXPORT const char *fmi2GetVersion(void) { return "2.0"; }                                                 \
    EXPORT void fmi2FreeInstance(fmi2Component c) { free(c); }                                                \
    EXPORT fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean on, size_t n, const fmi2String cats[]) { \
        (void)c; (void)on; (void)n; (void)cats; return fmi2OK;                                                \
    }                                                                                                         \
    EXPORT fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean tol_on, fmi2Real tol, fmi2Real t0,     \
                                          fmi2Boolean stop_on, fmi2Real stop) {                               \
        (void)tol_on; (void)tol; (void)stop_on; (void)stop; ((TYPE *)c)->t = t0; return fmi2OK;              \
    }                                                                                                         \
    EXPORT fmi2Status fmi2EnterInitializationMode(fmi2Component c) { (void)c; return fmi2OK; }                \
    EXPORT fmi2Status fmi2Terminate(fmi2Component c) { (void)c; return fmi2OK; }

/* the calls neither test FMU supports: fmi2Error */
#define REFUSE(decl) EXPORT fmi2Status decl { return fmi2Error; }
#define FMI2_TEST_REFUSALS                                                                                    \
REFUSE(fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Boolean v[]))                     \
REFUSE(fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2String v[]))                       \
REFUSE(fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Boolean v[]))               \
REFUSE(fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2String v[]))                 \
REFUSE(fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate s, size_t *size))                                     \
REFUSE(fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate s, fmi2Byte b[], size_t size))                             \
REFUSE(fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte b[], size_t size, fmi2FMUstate *s))                    \
REFUSE(fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference a[], size_t na,                         \
                                    const fmi2ValueReference b[], size_t nb, const fmi2Real dv[], fmi2Real df[]))     \
REFUSE(fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t n,                         \
                                    const fmi2Integer order[], fmi2Real value[]))                                     \
REFUSE(fmi2CancelStep(fmi2Component c))                                                                               \
REFUSE(fmi2GetStatus(fmi2Component c, const fmi2StatusKind s, fmi2Status *value))                                     \
REFUSE(fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind s, fmi2Real *value))                                   \
REFUSE(fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind s, fmi2Integer *value))                             \
REFUSE(fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind s, fmi2Boolean *value))                             \
REFUSE(fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind s, fmi2String *value))
#endif
