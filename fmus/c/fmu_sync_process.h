/* fmu-sync: the one record per process that every fmu-sync binary shares, so that they agree on who
 * starts the interpreter (fmu_sync_runtime.c, "one interpreter start per process"; docs/fmu.md "The
 * binary"). It lives in its own small library, FSR_PROCESS_LIB beside the FMU's binary
 * (fmu_sync_process.c, built at export), which exports nothing but FSR_PROCESS_SYMBOL: loading it
 * RTLD_GLOBAL cannot put any other symbol (an FMI function) before another library's own. The layout
 * is fixed for the symbol's version (v1). */
#ifndef FMU_SYNC_PROCESS_H
#define FMU_SYNC_PROCESS_H
#include <pthread.h>

#define FSR_PROCESS_SYMBOL "fmu_sync_process_v1"

typedef struct fsr_process {
    pthread_mutex_t lock;       /* held while the interpreter is chosen and started */
    int embedded;               /* 1 once an fmu-sync binary started it (a plain C host) */
    char tried[3000];           /* how fsp_find chose that interpreter */
} fsr_process;

typedef fsr_process *(*fsr_process_getter)(void);
#endif
