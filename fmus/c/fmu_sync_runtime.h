/* fmu-sync instance runtime: the Python embedding under the FMI glue.
 *
 * Embedding API (fmu_sync_runtime.c). An FMI glue (fmu_sync_fmi2.c; an FMI 3.0
 * glue calls the same functions) owns the FMI state machine and the logger;
 * everything Python, and the communication step, is here:
 *
 *   fsr_resources_path(uri, path)   file: URI of the resources folder -> local path
 *   fsr_start(resdir)               once per process (thread-safe): the host's interpreter if it
 *                                   runs one, else the one fsp_find chooses (FMU_SYNC_PYTHON, the
 *                                   interpreter recorded at export, python3 on PATH), initialised;
 *                                   then the FMU's boot module imported
 *   fsr_new(inst, resdir, name, guid)  a Python FMUInstance (fmus/runtime.py) and its layout
 *                                   (variable array x, per-variable table, work array)
 *   fsr_call(inst, method)          a reply method of the instance ("exit_initialization",
 *                                   "refresh", "reset", "inadmissible"), GIL taken inside
 *   fsr_state_get / _set / _free    FMU states: native copies of the variable array x and the
 *                                   work array (no Python, no GIL); a state belongs to the
 *                                   instance that saved it (fsr_state_of refuses any other)
 *   fsr_state_serialize / _deserialize   the sealed JSON form (Python: built from / checked into
 *                                   such a copy)
 *   fsr_step(inst, t, H)            one communication step: argument checks (H, t, stopTime,
 *                                   a time that advances, the internal-step limit), the native
 *                                   stepper (fmu_sync_native.h) called, no Python, no GIL;
 *                                   a step that cannot complete is FSR_ERROR, rolled back
 *   fsr_outputs(inst, call)         outputs of a direct-feedthrough FMU from its current inputs
 *                                   (the stepper with H = 0), no Python, no GIL
 *   fsr_free(inst)
 *
 * Every call that can fail returns an fsr status, numerically equal to fmi2Status and
 * fmi3Status (OK, Warning, Discard, Error, Fatal), and passes each message to the
 * instance's log callback (status, text); the glue decides which reach its importer.
 * FSR_FATAL means the Python slave raised: the instance is unusable.
 */
#ifndef FMU_SYNC_RUNTIME_H
#define FMU_SYNC_RUNTIME_H
#include <stddef.h>
#include <stdint.h>

/* Every number shared with the Python side (work-array slots FSR_H_*, stepper codes
 * FSR_R_*, phases FSR_INSTANTIATED.., table codes FSR_T_* / FSR_C_*, layout FSR_L_*,
 * schemes FSR_SCHEME_*, FSR_MAX_SUBSTEPS, the one version FSR_VERSION) and this export's
 * FMU_SYNC_GUID and FMU_SYNC_BOOT: generated at export from the Python definitions
 * (fmu_sync.export.constants_header); never written by hand. */
#include "fmu_sync_constants.h"

enum { FSR_OK = 0, FSR_WARNING = 1, FSR_DISCARD = 2, FSR_ERROR = 3, FSR_FATAL = 4 };

typedef void (*fsr_log)(void *ctx, int status, const char *text);

typedef struct fsr_instance {
    void *obj;                      /* the Python FMUInstance (a PyObject *) */
    fsr_log log;
    void *log_ctx;
    unsigned nvars;
    double *x;                      /* all variables, indexed by value reference */
    const int32_t *vtype, *vcaus;
    const double *vmin, *vmax;
    double *work;
    const char **name_of;           /* per variable: its name */
    const char **hint_of;           /* per variable: its allowed values ("" if a range) */
    int stop_defined;               /* the experiment's stopTime (doStep must not pass it) */
    double stop_time;
    size_t nwork;                   /* slots of the work array (its FSR_H_LEN) */
    uint64_t serial;                /* this instance among the process's: the owner of its FMU states */
} fsr_instance;

typedef struct fsr_state fsr_state;  /* a saved FMU state (opaque) */

int fsr_resources_path(const char *uri, char *out, size_t n, char *err, size_t en);
/* 1 if path is a folder this process can open (no stat: glibc floor, fmu_sync_runtime.c) */
int fsr_is_dir(const char *path);
int fsr_start(const char *resdir, char *err, size_t n);
int fsr_new(fsr_instance *inst, const char *resdir, const char *name, const char *guid, char *err, size_t n);
void fsr_free(fsr_instance *inst);
int fsr_call(fsr_instance *inst, const char *method);

/* the state behind handle if inst saved it; else NULL with the reason logged as FSR_ERROR under call
 * (NULL, freed, not a state of this FMU, or saved by another instance); fsr_state_check: the same
 * without a message */
fsr_state *fsr_state_of(fsr_instance *inst, const char *call, void *handle);
fsr_state *fsr_state_check(const fsr_instance *inst, void *handle);
/* save the instance's state into *st (overwritten in place if *st is a state of inst; a new state
 * if it is NULL or no state; FSR_ERROR if it is another instance's) */
int fsr_state_get(fsr_instance *inst, const char *call, fsr_state **st);
/* restore st (a state of inst: fsr_state_of): a copy back, no Python */
int fsr_state_set(fsr_instance *inst, fsr_state *st);
void fsr_state_free(fsr_state *st);
/* out == NULL: only *size; else copy exactly cap bytes (cap must be the size) */
int fsr_state_serialize(fsr_instance *inst, const char *call, fsr_state *st, char *out, size_t cap, size_t *size);
int fsr_state_deserialize(fsr_instance *inst, const char *call, const char *data, size_t size, fsr_state **out);

/* one communication step from t by H; on a refusal nothing changed */
int fsr_step(fsr_instance *inst, double t, double H);
/* direct feedthrough (work[FSR_H_FEEDTHROUGH] != 0): the outputs recomputed from the current
 * inputs by the stepper (H = 0, no Python, no GIL); FSR_ERROR if they are not finite */
int fsr_feedthrough(const fsr_instance *inst);
int fsr_outputs(fsr_instance *inst, const char *call);

/* Which Python a plain C host runs the FMU with (fmu_sync_python.c; the order: docs/fmu.md
 * "How it finds Python"). 0 with err naming every interpreter tried, what it lacked and the
 * command that fixes it on this platform. */
typedef struct fsp_choice {
    char program[1024];             /* the interpreter (Py_SetProgramName: its environment) */
    char lib[1024];                 /* its libpython */
    char tried[3000];               /* how it was chosen, for the FMU's own messages */
} fsp_choice;
int fsp_find(const char *resdir, fsp_choice *out, char *err, size_t n);
/* "key = value" (or KEY=value, KEY="value") of a text file; 0 if absent */
int fsp_read_key(const char *path, const char *key, char *out, size_t n);

/* helpers for messages */
const char *fsr_g(double v);                  /* shortest round-trip text of a double */
const char *fsr_caus_name(int causality);
void fsr_bound_text(const fsr_instance *inst, unsigned vr, char *out, size_t n);
int fsr_logf(fsr_instance *inst, int status, const char *fmt, ...) __attribute__((format(printf, 3, 4)));

#endif
