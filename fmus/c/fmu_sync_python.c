/* fmu-sync: which Python a plain C host runs the FMU with (API: fsp_find in fmu_sync_runtime.h;
 * the order and the messages: docs/fmu.md "How it finds Python").
 *
 * Written for fmu-sync (MIT). Everything is decided from files, without running an interpreter
 * (no child process in the host's process, no time spent): an interpreter's version and
 * environment come from its venv's pyvenv.cfg or its real name (.../bin/python3.11), its shared
 * library from its prefix, and numpy from its site folders (a numpy/ package there, or in a
 * folder a .pth file or PYTHONPATH adds). The Python host's own interpreter is taken before any
 * of this (fmu_sync_runtime.c). Order:
 *   1. FMU_SYNC_PYTHON (an explicit choice: used if its library is found, else an error);
 *   2. the interpreter recorded at export (resources/fmu_sync_python.txt), if it still exists,
 *      its library loads and it has numpy;
 *   3. each python3 on PATH (or /usr/local/bin:/usr/bin:/bin when PATH is unset), first with numpy.
 * None with numpy but one with its library: that one (the FMU's own check then names what it
 * lacks). None with its library: an error naming every candidate, what it lacked and the one
 * command that fixes it on this platform (/etc/os-release: apt-get on Debian/Ubuntu, dnf on
 * Fedora/RHEL).
 */
#define _GNU_SOURCE
#include <dirent.h>
#include <errno.h>
#include <limits.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "fmu_sync_runtime.h"

typedef struct {
    char exe[1024];
    char lib[1024];        /* its shared library, "" if none was found */
    char ver[16];          /* "3.11" */
    char prefix[1024];     /* the base installation: <prefix>/bin/python3.11 */
    char venv[1024];       /* the venv's folder, "" if not a venv */
    int system_site;       /* a venv that sees the base's site-packages */
    int numpy;             /* numpy found in its site folders */
    char why[600];         /* what it lacks, "" if usable */
} cand;

static void trim_end(char *s) {
    size_t k = strlen(s);
    while (k && (s[k - 1] == '\n' || s[k - 1] == '\r' || s[k - 1] == ' ' || s[k - 1] == '\t')) s[--k] = '\0';
}

int fsp_read_key(const char *path, const char *key, char *out, size_t n) {
    FILE *f = fopen(path, "r");
    if (!f) return 0;
    char line[4096];
    size_t kl = strlen(key);
    int found = 0;
    while (!found && fgets(line, sizeof line, f)) {
        if (strncmp(line, key, kl) != 0) continue;
        const char *p = line + kl;
        while (*p == ' ' || *p == '\t') ++p;
        if (*p != '=' && *p != ':') continue;   /* key = value, or KEY=value (os-release) */
        ++p;
        while (*p == ' ' || *p == '\t' || *p == '"') ++p;
        snprintf(out, n, "%s", p);
        trim_end(out);
        size_t k = strlen(out);
        if (k && out[k - 1] == '"') out[k - 1] = '\0';
        found = 1;
    }
    fclose(f);
    return found;
}

static int readable(const char *fmt, const char *a, const char *b) {
    char p[PATH_MAX];
    snprintf(p, sizeof p, fmt, a, b);
    return access(p, R_OK) == 0;
}

/* numpy/ in dir, or in a folder one of dir's .pth files names */
static int numpy_in(const char *dir) {
    if (readable("%s/numpy/__init__.py", dir, "")) return 1;
    DIR *d = opendir(dir);
    if (!d) return 0;
    int found = 0;
    struct dirent *e;
    while (!found && (e = readdir(d))) {
        size_t k = strlen(e->d_name);
        if (k < 5 || strcmp(e->d_name + k - 4, ".pth") != 0) continue;
        char pth[PATH_MAX], line[PATH_MAX];
        snprintf(pth, sizeof pth, "%s/%s", dir, e->d_name);
        FILE *f = fopen(pth, "r");
        if (!f) continue;
        while (!found && fgets(line, sizeof line, f)) {
            trim_end(line);
            if (!line[0] || line[0] == '#' || strncmp(line, "import", 6) == 0) continue;
            found = line[0] == '/' ? readable("%s%s/numpy/__init__.py", "", line)
                                   : readable("%s/%s/numpy/__init__.py", dir, line);
        }
        fclose(f);
    }
    closedir(d);
    return found;
}

static int has_numpy(const cand *c) {
    char dir[PATH_MAX];
    const char *pp = getenv("PYTHONPATH");
    if (pp && *pp) {
        char buf[8192];
        snprintf(buf, sizeof buf, "%s", pp);
        for (char *save = NULL, *tok = strtok_r(buf, ":", &save); tok; tok = strtok_r(NULL, ":", &save))
            if (numpy_in(tok)) return 1;
    }
    static const char *const venv_sites[] = {"%s/lib/python%s/site-packages", "%s/lib64/python%s/site-packages"};
    static const char *const base_sites[] = {"%s/lib/python%s/site-packages", "%s/lib64/python%s/site-packages",
                                             "%s/local/lib/python%s/dist-packages", "%s/lib/python3/dist-packages"};
    if (c->venv[0])
        for (size_t i = 0; i < sizeof venv_sites / sizeof *venv_sites; ++i) {
            snprintf(dir, sizeof dir, venv_sites[i], c->venv, c->ver);
            if (numpy_in(dir)) return 1;
        }
    if (c->venv[0] && !c->system_site) return 0;
    const char *home = getenv("HOME");
    if (home && !getenv("PYTHONNOUSERSITE")) {
        snprintf(dir, sizeof dir, "%s/.local/lib/python%s/site-packages", home, c->ver);
        if (numpy_in(dir)) return 1;
    }
    for (size_t i = 0; i < sizeof base_sites / sizeof *base_sites; ++i) {
        snprintf(dir, sizeof dir, base_sites[i], c->prefix, c->ver);
        if (numpy_in(dir)) return 1;
    }
    return 0;
}

/* An interpreter's version, prefix, venv and library, from files. 0 (c->why set) if it is missing,
 * its version cannot be told or it has no shared library. */
static int describe(const char *exe, cand *c) {
    memset(c, 0, sizeof *c);
    snprintf(c->exe, sizeof c->exe, "%s", exe);
    if (exe[0] != '/') {
        snprintf(c->why, sizeof c->why, "not an absolute path");
        return 0;
    }
    if (access(exe, X_OK) != 0) {
        snprintf(c->why, sizeof c->why, "%s", errno == ENOENT ? "does not exist" : strerror(errno));
        return 0;
    }
    char bin[1024], cfg[1100], home[1024] = "", ver[64] = "";
    snprintf(bin, sizeof bin, "%s", exe);
    *strrchr(bin, '/') = '\0';
    snprintf(cfg, sizeof cfg, "%s/../pyvenv.cfg", bin);
    if (access(cfg, R_OK) != 0) snprintf(cfg, sizeof cfg, "%s/pyvenv.cfg", bin);
    if (fsp_read_key(cfg, "home", home, sizeof home)) {
        if (!fsp_read_key(cfg, "version", ver, sizeof ver)) fsp_read_key(cfg, "version_info", ver, sizeof ver);
        snprintf(c->venv, sizeof c->venv, "%s", cfg);
        *strrchr(c->venv, '/') = '\0';
        char yes[16] = "";
        c->system_site = fsp_read_key(cfg, "include-system-site-packages", yes, sizeof yes) &&
                         strcmp(yes, "true") == 0;
    } else {
        char real[PATH_MAX];
        if (!realpath(exe, real)) {
            snprintf(c->why, sizeof c->why, "cannot resolve it (%s)", strerror(errno));
            return 0;
        }
        char *base = strrchr(real, '/');
        *base++ = '\0';
        snprintf(home, sizeof home, "%s", real);
        if (strncmp(base, "python", 6) == 0) snprintf(ver, sizeof ver, "%s", base + 6);
    }
    char *dot = strchr(ver, '.');               /* "3.11.7" or "3.11.7.final.0" -> "3.11" */
    if (dot && (dot = strchr(dot + 1, '.'))) *dot = '\0';
    if (!ver[0] || !strchr(ver, '.')) {
        snprintf(c->why, sizeof c->why, "cannot tell its Python version (no pyvenv.cfg with 'version', and its "
                 "real name is not pythonX.Y)");
        return 0;
    }
    snprintf(c->ver, sizeof c->ver, "%s", ver);
    size_t hl = strlen(home);
    while (hl > 1 && home[hl - 1] == '/') home[--hl] = '\0';
    char *up = strrchr(home, '/');
    if (up && up != home) *up = '\0';           /* <prefix>/bin -> <prefix> */
    snprintf(c->prefix, sizeof c->prefix, "%s", home);
    static const char *const forms[] = {"%s/lib/libpython%s.so.1.0", "%s/lib/libpython%s.so",
                                        "%s/lib64/libpython%s.so.1.0", "%s/lib/x86_64-linux-gnu/libpython%s.so.1.0",
                                        "%s/lib/aarch64-linux-gnu/libpython%s.so.1.0"};
    for (size_t i = 0; i < sizeof forms / sizeof *forms; ++i) {
        snprintf(c->lib, sizeof c->lib, forms[i], c->prefix, c->ver);
        if (access(c->lib, R_OK) == 0) break;
        c->lib[0] = '\0';
    }
    c->numpy = has_numpy(c);
    if (!c->lib[0])
        snprintf(c->why, sizeof c->why, "Python %s without its shared library libpython%s.so.1.0 (looked under "
                 "%s/lib)%s", c->ver, c->ver, c->prefix, c->numpy ? "" : " and without numpy");
    else if (!c->numpy)
        snprintf(c->why, sizeof c->why, "Python %s without numpy", c->ver);
    return c->lib[0] != '\0';
}

static void add_tried(char *tried, size_t n, const char *how, const cand *c) {
    size_t k = strlen(tried);
    snprintf(tried + k, n - k, "%s%s %s: %s", k ? "; " : "", how, c->exe, c->why[0] ? c->why : "usable");
}

/* The command that gives this machine what the candidate lacked (its library and maybe numpy); no
 * candidate at all: a Python with numpy and its library. */
static void fix_command(const cand *best, int any, char *out, size_t n) {
    char id[200] = "", like[200] = "", both[420];
    fsp_read_key("/etc/os-release", "ID", id, sizeof id);
    fsp_read_key("/etc/os-release", "ID_LIKE", like, sizeof like);
    snprintf(both, sizeof both, " %s %s ", id, like);
    int debian = strstr(both, "debian") || strstr(both, "ubuntu");
    int fedora = strstr(both, "fedora") || strstr(both, "rhel") || strstr(both, "centos");
    int distro = !any || strcmp(best->prefix, "/usr") == 0;      /* the distribution's own Python */
    int pip_numpy = any && !best->numpy && best->venv[0];         /* numpy into that venv with pip */
    char pip[1200] = "";
    if (pip_numpy) snprintf(pip, sizeof pip, ", then %s -m pip install numpy", best->exe);
    if (debian && distro) {
        char pkgs[200];
        if (!any) snprintf(pkgs, sizeof pkgs, "libpython3-dev python3-numpy");
        else snprintf(pkgs, sizeof pkgs, "libpython%s%s", best->ver, best->numpy || pip_numpy ? "" : " python3-numpy");
        snprintf(out, n, "on this Debian/Ubuntu machine run: sudo apt-get install %s%s", pkgs, pip);
    } else if (fedora && distro) {
        snprintf(out, n, "on this Fedora/RHEL machine run: sudo dnf install python3-libs%s%s",
                 !any || !(best->numpy || pip_numpy) ? " python3-numpy" : "", pip);
    } else {
        snprintf(out, n, "install a Python built with --enable-shared (python.org, conda, uv, or pyenv with "
                 "PYTHON_CONFIGURE_OPTS=--enable-shared) with numpy and set FMU_SYNC_PYTHON to it");
    }
}

int fsp_find(const char *resdir, fsp_choice *out, char *err, size_t n) {
    static cand c, first_lib, first_any;   /* under the runtime's lock */
    int have_lib = 0, have_any = 0;
    memset(out, 0, sizeof *out);
    const char *env = getenv("FMU_SYNC_PYTHON");
    if (env && *env) {
        if (!describe(env, &c)) {
            snprintf(err, n, "FMU_SYNC_PYTHON = %s: %s; set it to the interpreter of an environment with numpy "
                     "(a Python built with --enable-shared; on Debian/Ubuntu the libpython%s package)", env, c.why,
                     c.ver[0] ? c.ver : "3.X");
            return 0;
        }
        snprintf(out->program, sizeof out->program, "%s", env);
        snprintf(out->lib, sizeof out->lib, "%s", c.lib);
        snprintf(out->tried, sizeof out->tried, "FMU_SYNC_PYTHON %s (Python %s)", env, c.ver);
        return 1;
    }
    snprintf(out->tried, sizeof out->tried, "FMU_SYNC_PYTHON: not set");
    /* 2. the interpreter recorded at export */
    char manifest[PATH_MAX], program[1024] = "", lib[1024] = "";
    snprintf(manifest, sizeof manifest, "%s/fmu_sync_python.txt", resdir);
    fsp_read_key(manifest, "program", program, sizeof program);
    fsp_read_key(manifest, "libpython", lib, sizeof lib);
    if (program[0]) {
        int ok = describe(program, &c);
        if (!c.lib[0] && c.ver[0] && lib[0] && access(lib, R_OK) == 0) {   /* the recorded library itself */
            snprintf(c.lib, sizeof c.lib, "%s", lib);
            snprintf(c.why, sizeof c.why, c.numpy ? "%s" : "Python %s without numpy", c.numpy ? "" : c.ver);
            ok = 1;
        }
        if (access(program, F_OK) != 0)
            snprintf(c.why, sizeof c.why, "gone (the environment the FMU was exported from was removed, or this is "
                     "another machine)");
        add_tried(out->tried, sizeof out->tried, "the interpreter recorded at export", &c);
        if (ok && c.numpy) goto chosen;
        if (ok && !have_lib) { first_lib = c; have_lib = 1; }
        if (c.ver[0] && !have_any) { first_any = c; have_any = 1; }
    }
    /* 3. python3 on PATH */
    const char *path = getenv("PATH");
    int unset = !path || !*path;
    char buf[8192];
    snprintf(buf, sizeof buf, "%s", unset ? "/usr/local/bin:/usr/bin:/bin" : path);
    int seen = 0;
    static char real[8][PATH_MAX];        /* one entry per file: /bin is often /usr/bin */
    for (char *save = NULL, *dir = strtok_r(buf, ":", &save); dir; dir = strtok_r(NULL, ":", &save)) {
        char exe[1024], dir_real[PATH_MAX];
        snprintf(exe, sizeof exe, "%s/python3", dir);
        if (dir[0] != '/' || access(exe, X_OK) != 0 || !realpath(dir, dir_real)) continue;
        int dup = 0;
        for (int i = 0; i < seen && i < 8; ++i) dup |= strcmp(real[i], dir_real) == 0;
        if (dup) continue;
        if (seen < 8) snprintf(real[seen], PATH_MAX, "%s", dir_real);
        ++seen;
        int ok = describe(exe, &c);
        add_tried(out->tried, sizeof out->tried, unset ? "python3 on the default PATH (PATH is not set)"
                                                         : "python3 on PATH", &c);
        if (ok && c.numpy) goto chosen;
        if (ok && !have_lib) { first_lib = c; have_lib = 1; }
        if (c.ver[0] && !have_any) { first_any = c; have_any = 1; }
    }
    if (!seen) {
        size_t k = strlen(out->tried);
        snprintf(out->tried + k, sizeof out->tried - k, "; python3 on %sPATH (%s): none", unset ? "the default " : "",
                 unset ? "/usr/local/bin:/usr/bin:/bin" : path);
    }
    if (have_lib) {               /* no numpy seen: the FMU's own check says what is missing */
        c = first_lib;
        goto chosen;
    }
    char fix[600];
    fix_command(&first_any, have_any, fix, sizeof fix);
    snprintf(err, n, "no Python to run this FMU: it needs Python 3 with numpy and Python's shared library "
             "(libpython3.X.so.1.0). Tried: %s. To fix it, %s (or set FMU_SYNC_PYTHON to the interpreter of an "
             "environment with numpy)", out->tried, fix);
    return 0;
chosen:
    snprintf(out->program, sizeof out->program, "%s", c.exe);
    snprintf(out->lib, sizeof out->lib, "%s", c.lib);
    return 1;
}
