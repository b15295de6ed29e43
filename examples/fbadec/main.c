/* fbadec command line: decode face-object streams (.fba) to .fap text or fbaconf .npz. */
#include "fbadec.h"

#include <errno.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

enum { EXIT_INVALID = 1, EXIT_USAGE = 2, EXIT_IO = 3 };

typedef struct { uint8_t *p; size_t n, cap; int oom; } buf;

static void put(buf *b, const void *data, size_t n)
{
    if (b->oom) return;
    if (b->n + n > b->cap) {
        size_t nc = b->cap ? b->cap : 4096;
        while (nc < b->n + n) nc *= 2;
        uint8_t *q = realloc(b->p, nc);
        if (!q) { b->oom = 1; return; }
        b->p = q;
        b->cap = nc;
    }
    memcpy(b->p + b->n, data, n);
    b->n += n;
}

#if defined(__GNUC__)
static void putf(buf *b, const char *fmt, ...) __attribute__((format(printf, 2, 3)));
#endif
static void putf(buf *b, const char *fmt, ...)
{
    char tmp[512];
    va_list ap;
    va_start(ap, fmt);
    int k = vsnprintf(tmp, sizeof tmp, fmt, ap);
    va_end(ap);
    if (k > 0) put(b, tmp, (size_t)k < sizeof tmp ? (size_t)k : sizeof tmp - 1);
}

static void le(buf *b, uint64_t v, int bytes)
{
    uint8_t t[8];
    for (int i = 0; i < bytes; i++) t[i] = (uint8_t)(v >> (8 * i));
    put(b, t, (size_t)bytes);
}

/* Shortest decimal that reads back as the same double (integers without a point). */
static void format_rate(char *out, size_t n, double x)
{
    if (x == (double)(long long)x && x < 1e15) {
        snprintf(out, n, "%lld", (long long)x);
        return;
    }
    for (int p = 1; p <= 17; p++) {
        snprintf(out, n, "%.*g", p, x);
        if (strtod(out, NULL) == x) return;
    }
}

/* ---------------------------------------------------------------- .fap text (docs/fap-text.md) */
static int holds(uint8_t st) { return st == FBA_SET || st == FBA_RETAINED || st == FBA_DERIVED; }

static void write_fap(buf *b, const fba_result *r)
{
    char rate[64];
    format_rate(rate, sizeof rate, r->frame_rate);
    putf(b, "2.1 fbadec %s %zu\n", rate, r->n_frames);
    for (size_t f = 0; f < r->n_frames; f++) {
        const fba_frame *fr = &r->frames[f];
        for (int i = 0; i < FBA_NFAP; i++) putf(b, i ? " %d" : "%d", holds(fr->status[i]));
        putf(b, "\n%lld", (long long)fr->frame_number);
        if (holds(fr->status[0]))
            for (int k = 0; k < 4; k++) putf(b, " %d", (int)fr->high[k]);
        if (holds(fr->status[1]))
            for (int k = 4; k < 10; k++) putf(b, " %d", (int)fr->high[k]);
        for (int i = 2; i < FBA_NFAP; i++)
            if (holds(fr->status[i])) putf(b, " %d", (int)fr->value[i]);
        put(b, "\n", 1);
    }
}

/* ---------------------------------------------------------------- .npz (stored ZIP of .npy) */
static uint32_t crc32(const uint8_t *p, size_t n)
{
    static uint32_t table[256];
    if (!table[1]) {
        for (uint32_t i = 0; i < 256; i++) {
            uint32_t c = i;
            for (int k = 0; k < 8; k++) c = (c & 1) ? 0xEDB88320u ^ (c >> 1) : c >> 1;
            table[i] = c;
        }
    }
    uint32_t c = 0xFFFFFFFFu;
    for (size_t i = 0; i < n; i++) c = table[(c ^ p[i]) & 0xFF] ^ (c >> 8);
    return c ^ 0xFFFFFFFFu;
}

typedef struct { char name[32]; uint32_t crc, size, offset; } zentry;
typedef struct { buf out; zentry e[16]; int ne; } zip;

static void npy_begin(buf *b, const char *descr, const char *shape)
{
    char h[256];
    int n = snprintf(h, sizeof h, "{'descr': '%s', 'fortran_order': False, 'shape': %s, }", descr, shape);
    size_t total = 10 + (size_t)n + 1;
    size_t pad = (64 - total % 64) % 64;
    put(b, "\x93NUMPY\x01\x00", 8);
    le(b, (uint64_t)n + pad + 1, 2);
    put(b, h, (size_t)n);
    for (size_t i = 0; i < pad; i++) put(b, " ", 1);
    put(b, "\n", 1);
}

static void zip_add(zip *z, const char *name, const buf *npy)
{
    zentry *e = &z->e[z->ne++];
    snprintf(e->name, sizeof e->name, "%s.npy", name);
    e->crc = npy->oom ? 0 : crc32(npy->p, npy->n);
    e->size = (uint32_t)npy->n;
    e->offset = (uint32_t)z->out.n;
    le(&z->out, 0x04034b50, 4);
    le(&z->out, 20, 2); le(&z->out, 0, 2); le(&z->out, 0, 2);  /* version, flags, stored */
    le(&z->out, 0, 2); le(&z->out, 0x21, 2);                  /* 1980-01-01 00:00 */
    le(&z->out, e->crc, 4); le(&z->out, e->size, 4); le(&z->out, e->size, 4);
    le(&z->out, strlen(e->name), 2); le(&z->out, 0, 2);
    put(&z->out, e->name, strlen(e->name));
    put(&z->out, npy->p, npy->n);
    if (npy->oom) z->out.oom = 1;
}

static void zip_finish(zip *z)
{
    uint32_t cd = (uint32_t)z->out.n;
    for (int i = 0; i < z->ne; i++) {
        zentry *e = &z->e[i];
        le(&z->out, 0x02014b50, 4);
        le(&z->out, 20, 2); le(&z->out, 20, 2); le(&z->out, 0, 2); le(&z->out, 0, 2);
        le(&z->out, 0, 2); le(&z->out, 0x21, 2);
        le(&z->out, e->crc, 4); le(&z->out, e->size, 4); le(&z->out, e->size, 4);
        le(&z->out, strlen(e->name), 2); le(&z->out, 0, 2); le(&z->out, 0, 2);
        le(&z->out, 0, 2); le(&z->out, 0, 2); le(&z->out, 0, 4);
        le(&z->out, e->offset, 4);
        put(&z->out, e->name, strlen(e->name));
    }
    uint32_t cdsize = (uint32_t)z->out.n - cd;
    le(&z->out, 0x06054b50, 4);
    le(&z->out, 0, 2); le(&z->out, 0, 2);
    le(&z->out, (uint64_t)z->ne, 2); le(&z->out, (uint64_t)z->ne, 2);
    le(&z->out, cdsize, 4); le(&z->out, cd, 4); le(&z->out, 0, 2);
}

enum { F_VALUES, F_STATUS, F_HIGH, F_FN, F_TIME, F_INTRA, F_QUANT, F_CTYPE, F_OFFSET };

static void write_npz(buf *out, const fba_result *r)
{
    static const char *names[] = {"values", "status", "high", "frame_number", "time_ms",
                                  "is_intra", "fap_quant", "coding_type", "bit_offset"};
    static const char *descr[] = {"<i4", "|u1", "<i4", "<i8", "<f8", "|b1", "<i2", "|i1", "<i8"};
    zip z = {0};
    size_t n = r->n_frames;
    for (int a = F_VALUES; a <= F_OFFSET; a++) {
        buf b = {0};
        char shape[64];
        if (a == F_VALUES || a == F_STATUS) snprintf(shape, sizeof shape, "(%zu, %d)", n, FBA_NFAP);
        else if (a == F_HIGH) snprintf(shape, sizeof shape, "(%zu, %d)", n, FBA_NHIGH);
        else snprintf(shape, sizeof shape, "(%zu,)", n);
        npy_begin(&b, descr[a], shape);
        for (size_t f = 0; f < n; f++) {
            const fba_frame *fr = &r->frames[f];
            switch (a) {
            case F_VALUES: for (int i = 0; i < FBA_NFAP; i++) le(&b, (uint32_t)fr->value[i], 4); break;
            case F_STATUS: put(&b, fr->status, FBA_NFAP); break;
            case F_HIGH: for (int i = 0; i < FBA_NHIGH; i++) le(&b, (uint32_t)fr->high[i], 4); break;
            case F_FN: le(&b, (uint64_t)fr->frame_number, 8); break;
            case F_TIME: { uint64_t u; memcpy(&u, &fr->time_ms, 8); le(&b, u, 8); break; }
            case F_INTRA: le(&b, fr->is_intra ? 1 : 0, 1); break;
            case F_QUANT: le(&b, (uint16_t)fr->fap_quant, 2); break;
            case F_CTYPE: le(&b, (uint8_t)fr->coding_type, 1); break;
            default: le(&b, (uint64_t)fr->bit_offset, 8); break;
            }
        }
        zip_add(&z, names[a], &b);
        free(b.p);
    }
    buf b = {0};
    uint64_t u;
    npy_begin(&b, "<f8", "()");
    memcpy(&u, &r->frame_rate, 8);
    le(&b, u, 8);
    zip_add(&z, "frame_rate", &b);
    b.n = 0;
    npy_begin(&b, "<i8", "()");
    le(&b, (uint64_t)(int64_t)r->gender, 8);
    zip_add(&z, "gender", &b);
    b.n = 0;
    npy_begin(&b, "<U19", "()");
    for (const char *s = "fbaconf.FapFrames/1"; *s; s++) le(&b, (uint8_t)*s, 4);
    zip_add(&z, "format", &b);
    free(b.p);
    zip_finish(&z);
    *out = z.out;
}

/* ---------------------------------------------------------------- driver */
static int read_file(const char *path, uint8_t **data, size_t *len)
{
    FILE *f = fopen(path, "rb");
    if (!f) {
        fprintf(stderr, "fbadec: %s: %s\n", path, strerror(errno));
        return EXIT_IO;
    }
    buf b = {0};
    uint8_t tmp[65536];
    size_t k;
    while ((k = fread(tmp, 1, sizeof tmp, f)) > 0) {
        put(&b, tmp, k);
        if (b.n > (64u << 20)) break; /* far beyond any face stream; the decoder rejects it */
    }
    int bad = ferror(f) || b.oom;
    int e = errno;
    fclose(f);
    if (bad) {
        fprintf(stderr, "fbadec: %s: %s\n", path, b.oom ? "out of memory" : strerror(e));
        free(b.p);
        return EXIT_IO;
    }
    *data = b.p;
    *len = b.n;
    return 0;
}

static int write_file(const char *path, const buf *b)
{
    if (b->oom) {
        fprintf(stderr, "fbadec: %s: out of memory\n", path);
        return EXIT_IO;
    }
    FILE *f = fopen(path, "wb");
    if (!f) {
        fprintf(stderr, "fbadec: %s: %s\n", path, strerror(errno));
        return EXIT_IO;
    }
    int bad = fwrite(b->p, 1, b->n, f) != b->n;
    int e = errno;
    if (fclose(f) != 0 && !bad) { bad = 1; e = errno; }
    if (bad) {
        fprintf(stderr, "fbadec: %s: %s\n", path, strerror(e));
        remove(path);
        return EXIT_IO;
    }
    return 0;
}

static int ends_with(const char *s, const char *suf)
{
    size_t a = strlen(s), b = strlen(suf);
    return a >= b && strcmp(s + a - b, suf) == 0;
}

static int decode_file(const char *in, fba_result *res)
{
    uint8_t *data = NULL;
    size_t len = 0;
    int rc = read_file(in, &data, &len);
    if (rc) return rc;
    fba_error err;
    rc = fba_decode(data, len, res, &err) == 0 ? 0 : EXIT_INVALID;
    if (rc)
        fprintf(stderr, "fbadec: %s: %s at bit %lld: %s\n", in, err.rule,
                (long long)err.bit_offset, err.message);
    free(data);
    return rc;
}

static void render(buf *out, const fba_result *r, int fap)
{
    memset(out, 0, sizeof *out);
    if (fap) write_fap(out, r);
    else write_npz(out, r);
}

static int usage(void)
{
    fprintf(stderr, "usage: fbadec IN.fba OUT.fap|OUT.npz\n"
                    "       fbadec --out-dir DIR [--fap] IN1.fba [IN2.fba ...]\n"
                    "       fbadec --serve   (fbaconf's persistent protocol on stdin/stdout)\n");
    return EXIT_USAGE;
}

/* fbaconf's persistent protocol, version 2 (docs/fuzzing.md): per input "<id> <size> <output
 * path>\n" and <size> bytes on stdin; the answer "<id> <code>\n" on stdout, the code meaning
 * what the exit code of a one-shot run means (0 written, 1 invalid, 3 I/O). Ends at the end of
 * stdin. Added by the project after the independent writing, for fast fuzzing. */
static int serve(void)
{
    char line[4352];
    while (fgets(line, sizeof line, stdin)) {
        char *end;
        unsigned long long id = strtoull(line, &end, 10);
        char *sp = strchr(end + (*end == ' '), ' '), *nl = strchr(line, '\n');
        if (end == line || *end != ' ' || !sp || !nl) return EXIT_USAGE;
        *nl = 0;
        long long size = strtoll(end, NULL, 10);
        if (size < 0 || size > 64LL << 20) return EXIT_USAGE;
        uint8_t *data = malloc(size > 0 ? (size_t)size : 1);
        if (!data) return EXIT_IO;
        if (fread(data, 1, (size_t)size, stdin) != (size_t)size) { free(data); return EXIT_USAGE; }
        fba_result r;
        fba_error err;
        int rc = fba_decode(data, (size_t)size, &r, &err) == 0 ? 0 : EXIT_INVALID;
        free(data);
        if (rc) {
            fprintf(stderr, "fbadec: %s at bit %lld: %s\n", err.rule, (long long)err.bit_offset, err.message);
        } else {
            buf out;
            render(&out, &r, ends_with(sp + 1, ".fap"));
            rc = write_file(sp + 1, &out);
            free(out.p);
            fba_result_free(&r);
        }
        printf("%llu %d\n", id, rc);
        fflush(stdout);
    }
    return 0;
}

int main(int argc, char **argv)
{
    if (argc == 2 && !strcmp(argv[1], "--serve")) return serve();
    if (argc == 3 && argv[1][0] != '-') {
        int fap = ends_with(argv[2], ".fap"); /* anything else: .npz */
        fba_result r;
        int rc = decode_file(argv[1], &r);
        if (rc) return rc;
        buf out;
        render(&out, &r, fap);
        rc = write_file(argv[2], &out);
        free(out.p);
        fba_result_free(&r);
        return rc;
    }
    const char *dir = NULL;
    int fap = 0, first = 0;
    for (int i = 1; i < argc && !first; i++) {
        if (!strcmp(argv[i], "--out-dir") && i + 1 < argc) dir = argv[++i];
        else if (!strcmp(argv[i], "--fap")) fap = 1;
        else if (!strcmp(argv[i], "--npz")) fap = 0;
        else if (argv[i][0] == '-') return usage();
        else first = i;
    }
    if (!dir || !first) return usage();
    int n = argc - first;
    fba_result *res = calloc((size_t)n, sizeof *res);
    if (!res) return EXIT_IO;
    int rc = 0;
    for (int i = 0; i < n && !rc; i++) rc = decode_file(argv[first + i], &res[i]);
    for (int i = 0; i < n && !rc; i++) { /* all streams decoded: only now write anything */
        const char *in = argv[first + i], *base = strrchr(in, '/');
        base = base ? base + 1 : in;
        size_t stem = strlen(base);
        const char *dot = strrchr(base, '.');
        if (dot && dot != base) stem = (size_t)(dot - base);
        size_t plen = strlen(dir) + stem + 6;
        char *path = malloc(plen);
        if (!path) { rc = EXIT_IO; break; }
        snprintf(path, plen, "%s/%.*s.%s", dir, (int)stem, base, fap ? "fap" : "npz");
        buf out;
        render(&out, &res[i], fap);
        rc = write_file(path, &out);
        free(out.p);
        free(path);
    }
    for (int i = 0; i < n; i++) fba_result_free(&res[i]);
    free(res);
    return rc;
}
