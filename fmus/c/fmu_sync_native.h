/* fmu-sync native stepper (fmu_sync_native.c; compiled at export by fmu_sync/native.py).
 *
 *   fsr_native_step(x, work, t, H)   the FMU's stepper: numba cfunc compiled to x86-64 object
 *                                    code and linked into this binary (no Python, no GIL)
 *   fsr_native_errors                how many calls took the compiled code's exception path (all
 *                                    threads): a call during which it changed raised, and its
 *                                    result is not a status
 *   fsr_python_step(x, work, t, H)   the stepper for the Python slave (ctypes): its code, or -1
 *                                    if it raised
 */
#ifndef FMU_SYNC_NATIVE_H
#define FMU_SYNC_NATIVE_H
#include <stdint.h>

typedef int32_t (*fsr_native_fn)(double *x, double *work, double t, double H);
/* the variants compiled at export (fmu_sync.native.VARIANTS) and the one this CPU runs: the
 * x86-64-v3 (AVX2) code where the CPU has it, else the baseline (same numbers); the
 * environment variable FMU_SYNC_NATIVE_BASELINE=1 forces the baseline (tests) */
int32_t fsr_native_step_base(double *x, double *work, double t, double H);
int32_t fsr_native_step_v3(double *x, double *work, double t, double H);
extern fsr_native_fn fsr_native_step;
extern volatile unsigned fsr_native_errors;
int32_t fsr_python_step(double *x, double *work, double t, double H);

#endif
