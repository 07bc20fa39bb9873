/* fmu-sync native stepper support: what the stepper's object code (compiled from numba at
 * export, fmu_sync/native.py) needs besides the C library.
 *
 * Written for fmu-sync (MIT). The export renames the object's references to numba's runtime
 * and to CPython to fsrx_<name> (fmu_sync.native.RUNTIME); they are defined here:
 *
 * - allocation (numba's NRT API, same MemInfo layout: the object's inlined reference counting
 *   reads refct and data): one malloc'd block per array (meminfo, then the aligned data),
 *   freed when its count drops to zero; variable-size data (lists, strings) apart;
 * - the error path of the cfunc wrapper (an exception raised in compiled code): numba would
 *   take the GIL and print the exception; here nothing of Python is touched, the call is
 *   counted (fsr_native_errors) so that the step fails with a logged error instead of being
 *   taken for a success.
 */
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>

#include "fmu_sync_native.h"

typedef void (*dtor_fn)(void *ptr, size_t size, void *info);
typedef struct {
    size_t refct;               /* first field: the compiled code updates it atomically */
    dtor_fn dtor;
    void *dtor_info;
    void *data;                 /* fourth field: the compiled code reads it */
    size_t size;
    void *external_allocator;   /* unused */
} meminfo;

/* calls of the exception path, every thread (a plain counter: no TLS access per step) */
volatile unsigned fsr_native_errors;

fsr_native_fn fsr_native_step = fsr_native_step_base;

__attribute__((constructor)) static void choose_variant(void) {
    const char *base = getenv("FMU_SYNC_NATIVE_BASELINE");
    __builtin_cpu_init();
    if (!(base && base[0] == '1') && __builtin_cpu_supports("x86-64-v3")) fsr_native_step = fsr_native_step_v3;
}

int32_t fsr_python_step(double *x, double *work, double t, double H) {
    unsigned errors = fsr_native_errors;
    int32_t rc = fsr_native_step(x, work, t, H);
    return fsr_native_errors != errors ? -1 : rc;
}

static meminfo *new_meminfo(void *data, size_t size, dtor_fn dtor, void *info) {
    if (!data) return NULL;
    meminfo *mi = malloc(sizeof *mi);
    if (!mi) {
        free(data);
        return NULL;
    }
    mi->refct = 1;
    mi->dtor = dtor;
    mi->dtor_info = info;
    mi->data = data;
    mi->size = size;
    mi->external_allocator = NULL;
    return mi;
}

void *fsrx_NRT_Allocate(size_t size) { return malloc(size ? size : 1); }
void fsrx_NRT_Free(void *ptr) { free(ptr); }

/* meminfo and data in one block (one malloc per array, as numba's own runtime): the data
 * aligned to `align` after the header; freed with the meminfo (no destructor) */
static meminfo *alloc_block(size_t size, unsigned align) {
    size_t a = 16;
    while (a < align) a <<= 1;           /* a power of two, at least malloc's 16 */
    char *base = malloc(sizeof(meminfo) + a + size);
    if (!base) return NULL;
    meminfo *mi = (meminfo *)base;
    uintptr_t data = ((uintptr_t)(base + sizeof(meminfo)) + a - 1) & ~(uintptr_t)(a - 1);
    mi->refct = 1;
    mi->dtor = NULL;
    mi->dtor_info = NULL;
    mi->data = (void *)data;
    mi->size = size;
    mi->external_allocator = NULL;
    return mi;
}

meminfo *fsrx_NRT_MemInfo_alloc(size_t size) { return alloc_block(size, 16); }
meminfo *fsrx_NRT_MemInfo_alloc_aligned(size_t size, unsigned align) { return alloc_block(size, align); }

void fsrx_NRT_MemInfo_call_dtor(meminfo *mi) {
    if (mi->dtor) mi->dtor(mi->data, mi->size, mi->dtor_info);
    free(mi);
}

/* variable-size data (lists, strings): the element destructor in dtor_info */
static void varsize_dtor(void *ptr, size_t size, void *info) {
    (void)size;
    if (info && ptr) ((void (*)(void *))info)(ptr);
    free(ptr);
}

meminfo *fsrx_NRT_MemInfo_new_varsize_dtor(size_t size, dtor_fn dtor) {
    return new_meminfo(malloc(size ? size : 1), size, varsize_dtor, (void *)dtor);
}

void *fsrx_NRT_MemInfo_varsize_alloc(meminfo *mi, size_t size) {
    mi->data = malloc(size ? size : 1);
    if (mi->data) mi->size = size;
    return mi->data;
}

void *fsrx_NRT_MemInfo_varsize_realloc(meminfo *mi, size_t size) {
    void *data = realloc(mi->data, size ? size : 1);
    if (!data) return NULL;
    mi->data = data;
    mi->size = size;
    return data;
}

void fsrx_NRT_MemInfo_varsize_free(meminfo *mi, void *ptr) {
    free(ptr);
    if (ptr == mi->data) mi->data = NULL;
}

/* the exception path: flagged, no Python touched (results: NULL, 0 or nothing) */
#define FLAGGED(name) void *fsrx_##name(void) { __atomic_add_fetch(&fsr_native_errors, 1u, __ATOMIC_RELAXED); return NULL; }
#define QUIET(name) void *fsrx_##name(void) { return NULL; }
FLAGGED(numba_gil_ensure)
FLAGGED(numba_do_raise)
FLAGGED(numba_runtime_build_excinfo_struct)
FLAGGED(PyErr_SetString)
FLAGGED(PyErr_SetNone)
QUIET(numba_gil_release)
QUIET(numba_unpickle)
QUIET(PyErr_Clear)
QUIET(PyErr_WriteUnraisable)
QUIET(PyErr_Occurred)
QUIET(PyUnicode_FromString)
QUIET(PyUnicode_FromKindAndData)
QUIET(PyBytes_FromStringAndSize)
QUIET(PyObject_Hash)
QUIET(PyTuple_Pack)
QUIET(Py_DecRef)
QUIET(Py_IncRef)
#undef FLAGGED
#undef QUIET
void *fsrx_PyExc_RuntimeError, *fsrx_PyExc_StopIteration, *fsrx_PyExc_SystemError, *fsrx_PyExc_ValueError,
    *fsrx_PyExc_ZeroDivisionError, *fsrx_PyExc_IndexError, *fsrx_PyExc_TypeError, *fsrx_PyExc_OverflowError,
    *fsrx_PyExc_AssertionError;
