/* fba_mutator.c - fbaconf's structure-aware mutator of face object streams, for the coverage-guided
 * engines parser authors run: libFuzzer (LLVMFuzzerCustomMutator / LLVMFuzzerCustomCrossOver, built
 * with -DFBA_LIBFUZZER into the fuzz target) and AFL++ (the custom-mutator API, built with
 * -DFBA_AFL as a shared library for AFL_CUSTOM_MUTATOR_LIBRARY). Written by `fbaconf fuzz export`.
 *
 * Byte-level havoc breaks a face object stream at once: its planes are bit-packed headers followed by
 * arithmetic-coded payloads. This mutator knows the stream's layout as fbaconf's syntax model does
 * (fuzz/model.py; spec notes §1): planes between start codes (0x000001BA object, 0x000001BB plane,
 * 0x000001B1 end), and in the header of a plane that follows a start code every field with its bit
 * offset and width: is_intra, fba_object_mask, the frame rate (frame_rate, seconds,
 * frequency_offset), the time code (hours, minutes, marker, seconds), the skip chain, fap_quant, the
 * ten groups' marker, mask type and per-FAP mask bits, gender, coding_type, the is_new flags and the
 * min/max list values with their markers. It mutates a field in place (0, its largest value, +/-1,
 * a random value: the bits around it stay where they were), or whole planes at their start codes
 * (drop, duplicate, swap, truncate after one, splice planes of two inputs), so a mutation that
 * should keep a stream decodable does, and the decoder's deeper code is reached.
 * Not done here: re-encoding payload symbols through the arithmetic coder (fbaconf's own engine does
 * that in Python), and planes without a start code of their own, whose header starts where the
 * previous plane's arithmetic block ends (they are mutated with the plane before them). */
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#define FBA_MAX_PLANES 512
#define FBA_MAX_FIELDS 4096

typedef struct { uint64_t s; } fba_rng;

static uint32_t fba_rand(fba_rng *r)
{
    r->s ^= r->s << 13;
    r->s ^= r->s >> 7;
    r->s ^= r->s << 17;
    return (uint32_t)(r->s >> 11);
}

static uint32_t fba_below(fba_rng *r, uint32_t n) { return n ? fba_rand(r) % n : 0; }

typedef struct { size_t code, start, end; } fba_plane; /* start code at `code`; header bits from `start` */
typedef struct { size_t bit; int width; } fba_field;

static int is_code(const uint8_t *d, size_t n, size_t k)
{
    return k + 3 < n && d[k] == 0 && d[k + 1] == 0 && d[k + 2] == 1;
}

static int data_is_stuffing(uint8_t b) { return b == 0x7F; }

/* The planes: after the object start code, and after each plane start code, up to the next start code. */
static size_t fba_planes(const uint8_t *d, size_t n, fba_plane *out, size_t max)
{
    if (!is_code(d, n, 0) || d[3] != 0xBA) return 0;
    size_t np = 0, k = 0;
    while (k < n && np < max) {
        size_t next = k + 4;
        while (next < n && !is_code(d, n, next)) next++;
        if (d[k + 3] == 0xBA || d[k + 3] == 0xBB) {
            out[np].code = k;
            out[np].start = k + 4;
            out[np].end = next;
            /* a plane has bits of its own: not the lone stuffing byte (0x7F, next_start_code) that
             * separates the object start code from the first plane start code */
            if (next > k + 4 && !(next == k + 5 && data_is_stuffing(d[k + 4]))) np++;
        }
        if (next >= n || d[next + 3] == 0xB1) break;
        k = next;
    }
    return np;
}

static uint32_t fba_get(const uint8_t *d, size_t nbits, size_t bit, int w)
{
    uint32_t v = 0;
    for (int i = 0; i < w; i++, bit++)
        v = (v << 1) | (bit < nbits ? (uint32_t)((d[bit >> 3] >> (7 - (bit & 7))) & 1) : 0u);
    return v;
}

static void fba_set(uint8_t *d, size_t nbits, size_t bit, int w, uint32_t v)
{
    for (int i = w - 1; i >= 0; i--, bit++) {
        if (bit >= nbits) return;
        uint8_t m = (uint8_t)(1u << (7 - (bit & 7)));
        if ((v >> i) & 1) d[bit >> 3] |= m;
        else d[bit >> 3] &= (uint8_t)~m;
    }
}

static const int GROUP_SIZE[10] = {2, 16, 12, 8, 4, 5, 3, 10, 4, 4};

/* The header fields of the plane whose is_intra bit is at `bit` (spec notes §1.2-§1.4), up to `end`. */
static size_t fba_fields(const uint8_t *d, size_t end, size_t bit, fba_field *out, size_t nf, size_t max)
{
#define FIELD(w)                                                                    \
    do {                                                                            \
        if (bit + (w) > end || nf >= max) return nf;                               \
        out[nf].bit = bit;                                                          \
        out[nf++].width = (w);                                                      \
        bit += (w);                                                                 \
    } while (0)
#define VALUE(w) fba_get(d, end, bit - (size_t)(w), (w))
    FIELD(1);
    int intra = (int)VALUE(1);
    FIELD(2); /* fba_object_mask */
    if (intra) {
        FIELD(1);
        if (VALUE(1)) { FIELD(8); FIELD(4); FIELD(1); }            /* frame_rate, seconds, offset */
        FIELD(1);
        if (VALUE(1)) { FIELD(5); FIELD(6); FIELD(1); FIELD(6); } /* hh, mm, marker, ss */
    }
    FIELD(1);
    if (VALUE(1)) {
        for (int c = 0; c < 64; c++) { FIELD(4); if (VALUE(4) != 15) break; } /* skip chain */
    }
    if (!intra) return nf;
    FIELD(5); /* fap_quant */
    uint8_t coded[68] = {0};
    for (int g = 0, first = 0; g < 10; first += GROUP_SIZE[g], g++) {
        FIELD(1);
        FIELD(2);
        uint32_t type = VALUE(2);
        for (int j = 0; j < GROUP_SIZE[g]; j++) {
            if (type == 1 || type == 2) { FIELD(1); coded[first + j] = (uint8_t)VALUE(1); }
            else coded[first + j] = type == 3;
        }
    }
    FIELD(1); /* gender */
    FIELD(1);
    if (VALUE(1)) return nf; /* DCT segment mode: its payload follows */
    int flag[4];
    for (int l = 0; l < 4; l++) { FIELD(1); flag[l] = (int)VALUE(1); }
    for (int l = 0; l < 4; l++) {
        if (!flag[l]) continue;
        for (int g = 1, first = 2; g < 10; first += GROUP_SIZE[g], g++)
            for (int j = 0; j < GROUP_SIZE[g]; j++) {
                if (j % 4 == 0) FIELD(1);
                if (coded[first + j]) FIELD(5);
            }
    }
    return nf;
#undef FIELD
#undef VALUE
}

static size_t fba_move(uint8_t *d, size_t n, size_t max, size_t at, const uint8_t *src, size_t len, size_t cut)
{ /* replace d[at, at+cut) by src[0, len) */
    if (n - cut + len > max) return n;
    memmove(d + at + len, d + at + cut, n - at - cut);
    memcpy(d + at, src, len);
    return n - cut + len;
}

static const uint8_t END_CODE[4] = {0, 0, 1, 0xB1};

/* One structure-aware mutation of data[0, size) in place (at most max_size bytes); the new size. */
size_t fba_mutate(uint8_t *data, size_t size, size_t max_size, unsigned int seed)
{
    static fba_plane pl[FBA_MAX_PLANES];
    static fba_field fl[FBA_MAX_FIELDS];
    fba_rng r = {0x9E3779B97F4A7C15ULL ^ seed};
    size_t np = fba_planes(data, size, pl, FBA_MAX_PLANES);
    if (np == 0) { /* not a face object stream: one bit, as any fuzzer would */
        if (size) data[fba_below(&r, (uint32_t)size)] ^= (uint8_t)(1u << fba_below(&r, 8));
        return size;
    }
    uint32_t op = fba_below(&r, 10);
    if (op < 6) { /* a header field */
        size_t nf = 0;
        for (size_t p = 0; p < np && nf < FBA_MAX_FIELDS; p++)
            nf = fba_fields(data, pl[p].end * 8, pl[p].start * 8, fl, nf, FBA_MAX_FIELDS);
        if (nf) {
            fba_field f = fl[fba_below(&r, (uint32_t)nf)];
            uint32_t top = (f.width >= 32) ? 0xFFFFFFFFu : ((1u << f.width) - 1);
            uint32_t old = fba_get(data, size * 8, f.bit, f.width), v = old;
            switch (fba_below(&r, 5)) {
            case 0: v = 0; break;
            case 1: v = top; break;
            case 2: v = (v + 1) & top; break;
            case 3: v = (v - 1) & top; break;
            default: v = fba_rand(&r) & top;
            }
            if (v == old) v = (old + 1 + fba_below(&r, top)) & top; /* a mutation that changes nothing wastes a run */
            fba_set(data, size * 8, f.bit, f.width, v);
            return size;
        }
    }
    fba_plane a = pl[fba_below(&r, (uint32_t)np)], b = pl[fba_below(&r, (uint32_t)np)];
    size_t alen = a.end - a.code;
    if (op == 6 && np > 1 && a.code > 0) /* drop a plane (never the object start) */
        return fba_move(data, size, max_size, a.code, NULL, 0, alen);
    if (op == 7 && a.code > 0) { /* duplicate a plane */
        uint8_t *copy = malloc(alen);
        if (!copy) return size;
        memcpy(copy, data + a.code, alen);
        size_t n = fba_move(data, size, max_size, a.end, copy, alen, 0);
        free(copy);
        return n;
    }
    if (op == 8 && a.code > 0 && b.code > a.end) { /* swap two planes */
        size_t blen = b.end - b.code, total = b.end - a.code;
        uint8_t *tmp = malloc(total);
        if (!tmp) return size;
        memcpy(tmp, data + b.code, blen);
        memcpy(tmp + blen, data + a.end, b.code - a.end);
        memcpy(tmp + blen + (b.code - a.end), data + a.code, alen);
        memcpy(data + a.code, tmp, total);
        free(tmp);
        return size;
    }
    /* truncate after a plane (not the last), ending the stream with the end code */
    if (np < 2) return size;
    size_t keep = pl[fba_below(&r, (uint32_t)(np - 1))].end;
    if (keep + 4 > max_size) return size;
    memcpy(data + keep, END_CODE, 4);
    return keep + 4;
}

/* Planes of `a` up to one of them, then planes of `b` from one of them (into out, at most max). */
size_t fba_cross(const uint8_t *a, size_t na, const uint8_t *b, size_t nb, uint8_t *out, size_t max, unsigned int seed)
{
    static fba_plane pa[FBA_MAX_PLANES], pb[FBA_MAX_PLANES];
    fba_rng r = {0xD1B54A32D192ED03ULL ^ seed};
    size_t ka = fba_planes(a, na, pa, FBA_MAX_PLANES), kb = fba_planes(b, nb, pb, FBA_MAX_PLANES);
    if (!ka || kb < 2) {
        size_t n = na < max ? na : max;
        memcpy(out, a, n);
        return n;
    }
    size_t cut = pa[fba_below(&r, (uint32_t)ka)].end, from = pb[1 + fba_below(&r, (uint32_t)(kb - 1))].code;
    size_t tail = nb - from;
    if (cut + tail > max) tail = max > cut ? max - cut : 0;
    if (cut > max) cut = max;
    memcpy(out, a, cut);
    memcpy(out + cut, b + from, tail);
    return cut + tail;
}

#ifdef FBA_LIBFUZZER
size_t LLVMFuzzerMutate(uint8_t *data, size_t size, size_t max_size);

size_t LLVMFuzzerCustomMutator(uint8_t *data, size_t size, size_t max_size, unsigned int seed)
{
    if (seed % 4 == 0) return LLVMFuzzerMutate(data, size, max_size); /* keep a share of byte-level havoc */
    return fba_mutate(data, size, max_size, seed);
}

size_t LLVMFuzzerCustomCrossOver(const uint8_t *d1, size_t s1, const uint8_t *d2, size_t s2, uint8_t *out,
                                 size_t max_out, unsigned int seed)
{
    return fba_cross(d1, s1, d2, s2, out, max_out, seed);
}
#endif

#ifdef FBA_AFL
typedef struct { fba_rng r; uint8_t *buf; size_t cap; } fba_afl;

void *afl_custom_init(void *afl, unsigned int seed)
{
    (void)afl;
    fba_afl *m = calloc(1, sizeof *m);
    if (m) m->r.s = 0x2545F4914F6CDD1DULL ^ seed;
    return m;
}

size_t afl_custom_fuzz(void *data, uint8_t *buf, size_t buf_size, uint8_t **out_buf, uint8_t *add_buf,
                       size_t add_buf_size, size_t max_size)
{
    fba_afl *m = data;
    if (m->cap < max_size) {
        uint8_t *nb = realloc(m->buf, max_size);
        if (!nb) { *out_buf = buf; return buf_size; }
        m->buf = nb;
        m->cap = max_size;
    }
    unsigned int seed = fba_rand(&m->r);
    size_t n;
    if (add_buf && add_buf_size && seed % 8 == 0) {
        n = fba_cross(buf, buf_size, add_buf, add_buf_size, m->buf, max_size, seed);
    } else {
        n = buf_size < max_size ? buf_size : max_size;
        memcpy(m->buf, buf, n);
        n = fba_mutate(m->buf, n, max_size, seed);
    }
    *out_buf = m->buf;
    return n;
}

void afl_custom_deinit(void *data)
{
    fba_afl *m = data;
    if (m) free(m->buf);
    free(m);
}
#endif
