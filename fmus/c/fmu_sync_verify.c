/* fmu-sync: an FMU knows its own files (API: fsr_verify in fmu_sync_runtime.h; docs/fmu.md
 * "What the binary checks").
 *
 * Written for fmu-sync (MIT). Before anything of the resources folder runs, the binary checks that
 * the folder is its own: resources/fmu_sync_build.json carries this binary's GUID, and every file
 * that decides the FMU's behaviour matches the SHA-256 recorded at export (fsr_files, generated
 * beside the GUID by fmu_sync.export.build_binary: the build record, which holds the hash of the
 * carried code that the boot script checks before it imports it, the start file and the boot
 * script). SHA-256 as in FIPS 180-4, written here so that no library is needed.
 */
#include <errno.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmu_sync_runtime.h"

typedef struct {
    uint32_t h[8];
    uint64_t len;
    unsigned char buf[64];
    size_t fill;
} sha256_ctx;

static const uint32_t K[64] = {
    0x428a2f98, 0x71374491, 0xb5c0fbcf, 0xe9b5dba5, 0x3956c25b, 0x59f111f1, 0x923f82a4, 0xab1c5ed5,
    0xd807aa98, 0x12835b01, 0x243185be, 0x550c7dc3, 0x72be5d74, 0x80deb1fe, 0x9bdc06a7, 0xc19bf174,
    0xe49b69c1, 0xefbe4786, 0x0fc19dc6, 0x240ca1cc, 0x2de92c6f, 0x4a7484aa, 0x5cb0a9dc, 0x76f988da,
    0x983e5152, 0xa831c66d, 0xb00327c8, 0xbf597fc7, 0xc6e00bf3, 0xd5a79147, 0x06ca6351, 0x14292967,
    0x27b70a85, 0x2e1b2138, 0x4d2c6dfc, 0x53380d13, 0x650a7354, 0x766a0abb, 0x81c2c92e, 0x92722c85,
    0xa2bfe8a1, 0xa81a664b, 0xc24b8b70, 0xc76c51a3, 0xd192e819, 0xd6990624, 0xf40e3585, 0x106aa070,
    0x19a4c116, 0x1e376c08, 0x2748774c, 0x34b0bcb5, 0x391c0cb3, 0x4ed8aa4a, 0x5b9cca4f, 0x682e6ff3,
    0x748f82ee, 0x78a5636f, 0x84c87814, 0x8cc70208, 0x90befffa, 0xa4506ceb, 0xbef9a3f7, 0xc67178f2};

#define ROR(x, n) (((x) >> (n)) | ((x) << (32 - (n))))

static void block(sha256_ctx *c, const unsigned char *p) {
    uint32_t w[64], a, b, d, e, f, g, h, cc, t1, t2;
    for (int i = 0; i < 16; ++i)
        w[i] = (uint32_t)p[4 * i] << 24 | (uint32_t)p[4 * i + 1] << 16 | (uint32_t)p[4 * i + 2] << 8 | p[4 * i + 3];
    for (int i = 16; i < 64; ++i) {
        uint32_t s0 = ROR(w[i - 15], 7) ^ ROR(w[i - 15], 18) ^ (w[i - 15] >> 3);
        uint32_t s1 = ROR(w[i - 2], 17) ^ ROR(w[i - 2], 19) ^ (w[i - 2] >> 10);
        w[i] = w[i - 16] + s0 + w[i - 7] + s1;
    }
    a = c->h[0], b = c->h[1], cc = c->h[2], d = c->h[3], e = c->h[4], f = c->h[5], g = c->h[6], h = c->h[7];
    for (int i = 0; i < 64; ++i) {
        t1 = h + (ROR(e, 6) ^ ROR(e, 11) ^ ROR(e, 25)) + ((e & f) ^ (~e & g)) + K[i] + w[i];
        t2 = (ROR(a, 2) ^ ROR(a, 13) ^ ROR(a, 22)) + ((a & b) ^ (a & cc) ^ (b & cc));
        h = g, g = f, f = e, e = d + t1, d = cc, cc = b, b = a, a = t1 + t2;
    }
    c->h[0] += a, c->h[1] += b, c->h[2] += cc, c->h[3] += d, c->h[4] += e, c->h[5] += f, c->h[6] += g,
        c->h[7] += h;
}

static void sha_init(sha256_ctx *c) {
    static const uint32_t h0[8] = {0x6a09e667, 0xbb67ae85, 0x3c6ef372, 0xa54ff53a,
                                   0x510e527f, 0x9b05688c, 0x1f83d9ab, 0x5be0cd19};
    memcpy(c->h, h0, sizeof h0);
    c->len = 0;
    c->fill = 0;
}

static void sha_update(sha256_ctx *c, const unsigned char *p, size_t n) {
    c->len += n;
    while (n) {
        size_t k = 64 - c->fill < n ? 64 - c->fill : n;
        memcpy(c->buf + c->fill, p, k);
        c->fill += k, p += k, n -= k;
        if (c->fill == 64) {
            block(c, c->buf);
            c->fill = 0;
        }
    }
}

static void sha_hex(sha256_ctx *c, char out[65]) {
    uint64_t bits = c->len * 8;
    unsigned char pad = 0x80, zero = 0, len[8];
    sha_update(c, &pad, 1);
    while (c->fill != 56) sha_update(c, &zero, 1);
    for (int i = 0; i < 8; ++i) len[i] = (unsigned char)(bits >> (56 - 8 * i));
    sha_update(c, len, 8);
    for (int i = 0; i < 8; ++i) snprintf(out + 8 * i, 9, "%08x", c->h[i]);
}

/* the SHA-256 of a file as 64 hex digits; 0 (errno set) if it cannot be read */
int fsr_sha256_file(const char *path, char out[65]) {
    FILE *f = fopen(path, "rb");
    if (!f) return 0;
    sha256_ctx c;
    sha_init(&c);
    unsigned char buf[16384];
    size_t k;
    while ((k = fread(buf, 1, sizeof buf, f)) > 0) sha_update(&c, buf, k);
    int ok = !ferror(f);
    fclose(f);
    if (ok) sha_hex(&c, out);
    return ok;
}

/* the GUID in the build record's text ("guid": "{...}") into out ("" if none); 0 if it cannot be read */
static int guid_of(const char *path, char *out, size_t n) {
    out[0] = '\0';
    FILE *f = fopen(path, "rb");
    if (!f) return 0;
    char text[65536];
    size_t len = fread(text, 1, sizeof text - 1, f);
    fclose(f);
    text[len] = '\0';
    const char *p = strstr(text, "\"guid\": \"");
    const char *e = p ? strchr(p + 9, '"') : NULL;
    if (e) snprintf(out, n, "%.*s", (int)(e - p - 9), p + 9);
    return 1;
}

int fsr_verify(const char *resdir, char *err, size_t n) {
    char path[4200], got[65], guid[256];
    snprintf(path, sizeof path, "%s/fmu_sync_build.json", resdir);
    int readable = guid_of(path, guid, sizeof guid);
    if (strcmp(guid, FMU_SYNC_GUID) != 0) {
        if (guid[0])
            snprintf(err, n, "the resources folder %s is not this FMU's: resources/fmu_sync_build.json carries "
                     "GUID '%s', this binary's is '%s' (another FMU's resources/ unpacked over this one?); "
                     "unpack this FMU afresh into an empty folder", resdir, guid, FMU_SYNC_GUID);
        else
            snprintf(err, n, "the resources folder %s is not this FMU's: resources/fmu_sync_build.json: %s "
                     "(it must carry this binary's GUID '%s'); unpack this FMU afresh into an empty folder",
                     resdir, readable ? "has no GUID" : strerror(errno), FMU_SYNC_GUID);
        return 0;
    }
    for (const char *const *e = fsr_files; e[0]; e += 2) {
        snprintf(path, sizeof path, "%s/%s", resdir, e[0]);
        if (!fsr_sha256_file(path, got)) {
            snprintf(err, n, "resources/%s cannot be read in %s (%s): the FMU is incomplete; unpack it afresh",
                     e[0], resdir, strerror(errno));
            return 0;
        }
        if (strcmp(got, e[1]) != 0) {
            snprintf(err, n, "resources/%s in %s was changed after export (SHA-256 %.12s..., recorded "
                     "%.12s...): the FMU runs only the files it was exported with; to change a start value, "
                     "set it with fmi2SetReal / fmi3SetFloat64 before initialization or export the FMU again "
                     "(fmu-sync export --set)", e[0], resdir, got, e[1]);
            return 0;
        }
    }
    return 1;
}
