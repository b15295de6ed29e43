/* fbadec.c - MPEG-4 face-object (FAP) stream decoder: frame-based arithmetic mode
 * (spec notes §1-§3, D1-D7, D9) and fbaconf's provisional DCT segment mode
 * (docs/dct-mode.md, bitstreams/data/dct_provisional.toml).
 * Written independently from the specification text; see NOTES.md. */
#include "fbadec.h"

#include <setjmp.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* ---------------------------------------------------------------- tables */
/* Tables transcribed from bitstreams/data/fap_table.csv (spec notes §2) and
 * bitstreams/data/dct_provisional.toml. Index i = FAP i+1. */
struct ac_code { uint8_t run, level, len; uint16_t code; };

static const int32_t DCT_M[16][16] = {
  {4096, 4096, 4096, 4096, 4096, 4096, 4096, 4096, 4096, 4096, 4096, 4096, 4096, 4096, 4096, 4096},
  {5765, 5543, 5109, 4478, 3675, 2731, 1682, 568, -568, -1682, -2731, -3675, -4478, -5109, -5543, -5765},
  {5681, 4816, 3218, 1130, -1130, -3218, -4816, -5681, -5681, -4816, -3218, -1130, 1130, 3218, 4816, 5681},
  {5543, 3675, 568, -2731, -5109, -5765, -4478, -1682, 1682, 4478, 5765, 5109, 2731, -568, -3675, -5543},
  {5352, 2217, -2217, -5352, -5352, -2217, 2217, 5352, 5352, 2217, -2217, -5352, -5352, -2217, 2217, 5352},
  {5109, 568, -4478, -5543, -1682, 3675, 5765, 2731, -2731, -5765, -3675, 1682, 5543, 4478, -568, -5109},
  {4816, -1130, -5681, -3218, 3218, 5681, 1130, -4816, -4816, 1130, 5681, 3218, -3218, -5681, -1130, 4816},
  {4478, -2731, -5543, 568, 5765, 1682, -5109, -3675, 3675, 5109, -1682, -5765, -568, 5543, 2731, -4478},
  {4096, -4096, -4096, 4096, 4096, -4096, -4096, 4096, 4096, -4096, -4096, 4096, 4096, -4096, -4096, 4096},
  {3675, -5109, -1682, 5765, -568, -5543, 2731, 4478, -4478, -2731, 5543, 568, -5765, 1682, 5109, -3675},
  {3218, -5681, 1130, 4816, -4816, -1130, 5681, -3218, -3218, 5681, -1130, -4816, 4816, 1130, -5681, 3218},
  {2731, -5765, 3675, 1682, -5543, 4478, 568, -5109, 5109, -568, -4478, 5543, -1682, -3675, 5765, -2731},
  {2217, -5352, 5352, -2217, -2217, 5352, -5352, 2217, 2217, -5352, 5352, -2217, -2217, 5352, -5352, 2217},
  {1682, -4478, 5765, -5109, 2731, 568, -3675, 5543, -5543, 3675, -568, -2731, 5109, -5765, 4478, -1682},
  {1130, -3218, 4816, -5681, 5681, -4816, 3218, -1130, -1130, 3218, -4816, 5681, -5681, 4816, -3218, 1130},
  {568, -1682, 2731, -3675, 4478, -5109, 5543, -5765, 5765, -5543, 5109, -4478, 3675, -2731, 1682, -568},
};
static const int32_t DCT_SCALE[32] = {2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 14, 16, 18, 20, 22, 24, 27, 30, 33, 36, 40, 44, 48, 53, 58, 64, 70, 77, 85, 94, 104};
/* {run, level, length, code} */
static const struct ac_code AC_TABLE[] = {
  {0, 1, 2, 0x2},
  {0, 2, 4, 0xc},
  {0, 3, 5, 0x1a},
  {1, 1, 5, 0x1b},
  {0, 4, 6, 0x38},
  {0, 5, 6, 0x39},
  {0, 6, 7, 0x74},
  {0, 7, 7, 0x75},
  {0, 8, 7, 0x76},
  {1, 2, 7, 0x77},
  {2, 1, 7, 0x78},
  {0, 9, 8, 0xf2},
  {0, 10, 8, 0xf3},
  {0, 11, 8, 0xf4},
  {3, 1, 8, 0xf5},
  {0, 12, 9, 0x1ed},
  {0, 13, 9, 0x1ee},
  {0, 14, 9, 0x1ef},
  {0, 15, 9, 0x1f0},
  {0, 16, 9, 0x1f1},
  {1, 3, 9, 0x1f2},
  {4, 1, 9, 0x1f3},
  {0, 17, 10, 0x3e8},
  {0, 18, 10, 0x3e9},
  {0, 19, 10, 0x3ea},
  {0, 20, 10, 0x3eb},
  {0, 21, 10, 0x3ec},
  {0, 22, 10, 0x3ed},
  {0, 24, 10, 0x3ee},
  {1, 4, 10, 0x3ef},
  {5, 1, 10, 0x3f0},
  {0, 23, 11, 0x7e2},
  {0, 25, 11, 0x7e3},
  {0, 26, 11, 0x7e4},
  {0, 27, 11, 0x7e5},
  {0, 28, 11, 0x7e6},
  {0, 29, 11, 0x7e7},
  {0, 30, 11, 0x7e8},
  {0, 31, 11, 0x7e9},
  {0, 35, 11, 0x7ea},
  {1, 5, 11, 0x7eb},
  {2, 2, 11, 0x7ec},
  {6, 1, 11, 0x7ed},
  {0, 32, 12, 0xfdc},
  {0, 33, 12, 0xfdd},
  {0, 34, 12, 0xfde},
  {0, 36, 12, 0xfdf},
  {0, 37, 12, 0xfe0},
  {0, 38, 12, 0xfe1},
  {0, 39, 12, 0xfe2},
  {0, 40, 12, 0xfe3},
  {0, 41, 12, 0xfe4},
  {0, 42, 12, 0xfe5},
  {0, 43, 12, 0xfe6},
  {0, 44, 12, 0xfe7},
  {0, 52, 12, 0xfe8},
  {1, 6, 12, 0xfe9},
  {1, 7, 12, 0xfea},
  {2, 3, 12, 0xfeb},
  {8, 1, 12, 0xfec},
  {0, 45, 13, 0x1fda},
  {0, 46, 13, 0x1fdb},
  {0, 47, 13, 0x1fdc},
  {0, 48, 13, 0x1fdd},
  {0, 49, 13, 0x1fde},
  {0, 50, 13, 0x1fdf},
  {0, 51, 13, 0x1fe0},
  {0, 53, 13, 0x1fe1},
  {0, 54, 13, 0x1fe2},
  {0, 55, 13, 0x1fe3},
  {0, 56, 13, 0x1fe4},
  {0, 57, 13, 0x1fe5},
  {0, 59, 13, 0x1fe6},
  {0, 60, 13, 0x1fe7},
  {0, 61, 13, 0x1fe8},
  {0, 62, 13, 0x1fe9},
  {0, 65, 13, 0x1fea},
  {0, 66, 13, 0x1feb},
  {0, 70, 13, 0x1fec},
  {0, 73, 13, 0x1fed},
  {1, 8, 13, 0x1fee},
  {1, 9, 13, 0x1fef},
  {1, 10, 13, 0x1ff0},
  {1, 11, 13, 0x1ff1},
  {7, 1, 13, 0x1ff2},
  {0, 58, 14, 0x3fe6},
  {0, 63, 14, 0x3fe7},
  {0, 67, 14, 0x3fe8},
  {0, 68, 14, 0x3fe9},
  {0, 69, 14, 0x3fea},
  {0, 71, 14, 0x3feb},
  {0, 72, 14, 0x3fec},
  {0, 74, 14, 0x3fed},
  {0, 75, 14, 0x3fee},
  {0, 77, 14, 0x3fef},
  {0, 79, 14, 0x3ff0},
  {0, 80, 14, 0x3ff1},
  {0, 82, 14, 0x3ff2},
  {0, 83, 14, 0x3ff3},
  {0, 84, 14, 0x3ff4},
  {0, 86, 14, 0x3ff5},
  {0, 87, 14, 0x3ff6},
  {0, 93, 14, 0x3ff7},
  {0, 94, 14, 0x3ff8},
  {0, 95, 14, 0x3ff9},
  {1, 12, 14, 0x3ffa},
  {1, 14, 14, 0x3ffb},
  {2, 4, 14, 0x3ffc},
  {2, 5, 14, 0x3ffd},
  {3, 2, 14, 0x3ffe},
  {9, 1, 14, 0x3fff},
};
static const int16_t FAP_QP[68] = {1, 1, 4, 2, 2, 2, 2, 2, 2, 2, 2, 2, 2, 1, 1, 1, 1, 1, 1, 1, 1, 1, 128, 128, 128, 128, 1, 1, 1, 1, 2, 2, 2, 2, 2, 2, 1, 1, 2, 2, 2, 2, 1, 1, 1, 1, 512, 170, 170, 170, 2, 2, 2, 2, 2, 2, 2, 2, 2, 2, 1, 1, 1, 1, 1, 1, 1, 1};
static const int16_t FAP_IRANGE[68] = {0, 0, 1080, 600, 1860, 600, 600, 600, 600, 1860, 1860, 600, 600, 600, 1080, 1080, 1080, 420, 1080, 1080, 600, 600, 1200, 1200, 900, 900, 600, 600, 420, 420, 900, 900, 900, 900, 900, 900, 900, 900, 900, 900, 600, 600, 1080, 1080, 1080, 1080, 1080, 1860, 1860, 1860, 600, 1860, 600, 600, 600, 600, 1860, 1860, 600, 600, 540, 540, 680, 900, 900, 900, 900, 900};
static const int16_t FAP_PRANGE[68] = {0, 0, 360, 180, 600, 180, 180, 180, 180, 600, 600, 180, 180, 180, 360, 360, 360, 180, 600, 600, 240, 240, 420, 420, 300, 300, 180, 180, 120, 120, 360, 360, 360, 360, 360, 360, 300, 300, 300, 300, 180, 180, 420, 420, 420, 420, 420, 600, 600, 600, 180, 600, 180, 180, 180, 180, 600, 600, 180, 180, 120, 120, 180, 180, 240, 240, 300, 300};

/* FAP groups (spec notes §1.2): first FAP index (0-based) and size. */
static const int GROUP_FIRST[10] = {0, 2, 18, 30, 38, 42, 47, 50, 60, 64};
static const int GROUP_SIZE[10] = {2, 16, 12, 8, 4, 5, 3, 10, 4, 4};

#define AC_ESCAPE_LEN 9
#define AC_ESCAPE_CODE 0x1EC /* "111101100" */
#define DC_MAX_LEVEL 1048575
#define MAX_INPUT_BYTES (16u << 20)

/* Arithmetic coder constants (§3.1). */
#define AC_TOP 65535u
#define AC_Q1 16384u
#define AC_Q2 32768u
#define AC_Q3 49152u
#define AC_MAXFREQ 16383
#define AC_STUFF_RUN 22


/* ---------------------------------------------------------------- decoder state */
/* The model of §3.2 (frequencies from 1, +1 per symbol, halved once the total reaches 16383),
 * kept as a Fenwick tree of the frequencies: a symbol costs O(log n), where a cumulative table
 * costs O(n) per update, and alphabets reach 3,721 symbols (bounds of 31*60 at q = 1). A model is
 * uniform until its second update, so setting one up is O(1) (an intra plane sets up two per
 * coded FAP, most of which code a symbol or none before the next one does it again). */
typedef struct {
    int n, lo;            /* n symbols, symbol s means value lo + s */
    int cap;              /* symbols the arrays hold: grown to the alphabet when first needed */
    int uniform, one;     /* uniform but for symbol `one` (frequency 2; -1: none) */
    int32_t total;        /* cum[0] of §3.2: the sum of the frequencies */
    int32_t *freq, *tree; /* freq[0..n-1]; tree[1..n] the Fenwick sums of freq */
} model;

typedef struct {
    uint32_t low, high, value;
    int zrun;
    int64_t count;          /* arithmetic input bits read in this block */
    int64_t ipos[16];       /* stream position of the last 16 input bits */
    int64_t bad_at, bad_pos;/* pending stuffing violation (D7) */
} arith;

enum { HM_VS1, HM_VS2, HM_VB, HM_ES1, HM_EI1, HM_ES2, HM_EI2, HM_COUNT };

typedef struct {
    const uint8_t *buf;
    size_t len;
    int64_t nbits, pos;
    jmp_buf jb;
    fba_error *err;

    int64_t *sc; size_t nsc, capsc;   /* byte offsets of start codes consumed */

    int n_planes;
    int coding_type, fap_quant;
    int mask_type[10];
    uint8_t coded[FBA_NFAP];          /* coded in the current intra period */
    uint8_t ever_set[FBA_NFAP];
    int32_t last[FBA_NFAP];           /* last reconstructed value of FAPs 3..68 */
    int32_t hl[FBA_NHIGH];            /* last high-level fields */
    int32_t bound[4][FBA_NFAP];       /* D4: |I max|, |I min|, |P max|, |P min| in q=1 units */
    double rate, first_rate;
    int rate_seen, gender;
    int64_t prev_fn;
    double prev_time;

    model lm[2][FBA_NFAP];            /* [0] intra, [1] predicted */
    model hm[2][HM_COUNT];
    int32_t dc_prev[FBA_NFAP];
    uint8_t dc_valid[FBA_NFAP];

    fba_frame *frames;
    size_t n, cap;
} dec;

static void fail(dec *d, int64_t at, const char *rule, const char *fmt, ...)
{
    d->err->rule = rule;
    d->err->bit_offset = at;
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(d->err->message, sizeof d->err->message, fmt, ap);
    va_end(ap);
    longjmp(d->jb, 1);
}

/* ---------------------------------------------------------------- bit reading */
static int raw_bit(const dec *d, int64_t p)
{
    if (p < 0 || p >= d->nbits) return 0;
    return (d->buf[p >> 3] >> (7 - (p & 7))) & 1;
}

/* Fixed-length field; running past the end of the data is "truncated". */
static uint32_t bits(dec *d, int n, const char *what)
{
    if (d->pos + n > d->nbits)
        fail(d, d->pos, "truncated", "stream ends inside %s", what);
    uint32_t v = 0;
    for (int i = 0; i < n; i++) v = (v << 1) | (uint32_t)raw_bit(d, d->pos++);
    return v;
}

static void marker(dec *d, const char *what)
{
    int64_t at = d->pos;
    if (!bits(d, 1, what)) fail(d, at, "marker-zero", "%s is 0", what);
}

/* ---------------------------------------------------------------- arithmetic decoder (§3) */
static void model_init(model *m, int lo, int hi)
{
    m->lo = lo;
    m->n = hi - lo + 1;
    m->uniform = 1;
    m->one = -1;
    m->total = m->n;
}

static void tree_build(model *m)
{
    for (int i = 1; i <= m->n; i++) m->tree[i] = m->freq[i - 1];
    for (int i = 1; i <= m->n; i++) {
        int j = i + (i & -i);
        if (j <= m->n) m->tree[j] += m->tree[i];
    }
}

/* cum[k] of §3.2: the sum of freq[k..n-1] */
static int32_t cum(const model *m, int k)
{
    if (m->uniform) return m->n - k + (k <= m->one);
    int32_t below = 0;
    for (int i = k; i > 0; i -= i & -i) below += m->tree[i];
    return m->total - below;
}

/* The first k >= 1 with cum[k] <= target (cum descends to cum[n] = 0; target < cum[0]). */
static int find(const model *m, uint64_t target)
{
    if (m->uniform) {
        int64_t k = (int64_t)m->n - (int64_t)target;
        if (k < 1) k = 1;
        while ((uint64_t)cum(m, (int)k) > target) k++;
        return (int)k;
    }
    /* cum[k] <= target  <=>  freq[0] + ... + freq[k-1] >= total - target: descend the tree */
    int32_t need = m->total - (int32_t)target;
    int pos = 0, step = 1;
    while (step * 2 <= m->n) step *= 2;
    for (; step; step /= 2)
        if (pos + step <= m->n && m->tree[pos + step] < need) {
            pos += step;
            need -= m->tree[pos];
        }
    return pos + 1;
}

static void model_update(dec *d, model *m, int s)
{
    if (m->uniform && m->one < 0) {
        m->one = s;
        m->total++;
        return;
    }
    if (m->uniform) {
        if (m->n > m->cap) {
            int32_t *f = realloc(m->freq, (size_t)m->n * sizeof *f);
            if (f) m->freq = f;
            int32_t *t = f ? realloc(m->tree, ((size_t)m->n + 1) * sizeof *t) : NULL;
            if (!t) fail(d, d->pos, "out-of-memory", "cannot allocate a model of %d symbols", m->n);
            m->tree = t;
            m->cap = m->n;
        }
        for (int k = 0; k < m->n; k++) m->freq[k] = 1;
        m->freq[m->one]++;
        m->tree[0] = 0;
        tree_build(m);
        m->uniform = 0;
    }
    if (m->total >= AC_MAXFREQ) {
        m->total = 0;
        for (int k = 0; k < m->n; k++) {
            m->freq[k] = (m->freq[k] + 1) / 2;
            m->total += m->freq[k];
        }
        tree_build(m);
    }
    m->freq[s]++;
    m->total++;
    for (int i = s + 1; i <= m->n; i += i & -i) m->tree[i]++;
}

/* One arithmetic input bit, with the stuffing of §3.3: after 22 zeros a '1' follows and is
 * dropped. A '0' there is an error only if it belongs to the block, i.e. once 14 more input
 * bits have been read (D7); otherwise it lies in the handed-back look-ahead. */
static uint32_t arith_bit(dec *d, arith *a)
{
    int64_t p = d->pos++;
    int b = raw_bit(d, p);
    a->count++;
    a->ipos[a->count & 15] = p;
    if (a->bad_at >= 0 && a->count >= a->bad_at + 14) {
        if (a->bad_pos >= d->nbits)
            fail(d, a->bad_pos, "truncated", "stream ends inside an arithmetic block");
        fail(d, a->bad_pos, "bad-stuffing", "stuffing bit after 22 zeros is 0");
    }
    if (b) {
        a->zrun = 0;
    } else if (++a->zrun == AC_STUFF_RUN) {
        a->zrun = 0;
        int64_t sp = d->pos++;
        if (!raw_bit(d, sp) && a->bad_at < 0) {
            a->bad_at = a->count;
            a->bad_pos = sp;
        }
    }
    return (uint32_t)b;
}

static void arith_start(dec *d, arith *a)
{
    memset(a, 0, sizeof *a);
    a->bad_at = -1;
    a->high = AC_TOP;
    for (int i = 0; i < 16; i++) a->value = (a->value << 1) | arith_bit(d, a);
}

/* End of block (D7): the next field starts at the stream position of the first of the last
 * 14 input bits, i.e. right after the block's last input bit and any stuffing bit after it. */
static void arith_end(dec *d, arith *a)
{
    if (a->bad_at >= 0 && a->count >= a->bad_at + 14) /* cannot happen, kept for safety */
        fail(d, a->bad_pos, "bad-stuffing", "stuffing bit after 22 zeros is 0");
    d->pos = a->ipos[(a->count - 13) & 15];
    if (d->pos > d->nbits)
        fail(d, d->nbits, "truncated", "stream ends inside an arithmetic block");
}

static int arith_decode(dec *d, arith *a, model *m)
{
    if (a->value < a->low || a->value > a->high)
        fail(d, d->pos, "arith-state", "arithmetic decoder state out of range");
    uint64_t len = (uint64_t)a->high - a->low + 1;
    uint64_t c0 = (uint64_t)m->total;
    uint64_t target = (((uint64_t)a->value - a->low + 1) * c0 - 1) / len;
    int k = find(m, target);
    uint32_t nh = (uint32_t)(a->low - 1 + len * (uint64_t)cum(m, k - 1) / c0);
    uint32_t nl = (uint32_t)(a->low + len * (uint64_t)cum(m, k) / c0);
    a->high = nh;
    a->low = nl;
    for (;;) {
        if (a->high < AC_Q2) {
            /* nothing to subtract */
        } else if (a->low >= AC_Q2) {
            a->value -= AC_Q2; a->low -= AC_Q2; a->high -= AC_Q2;
        } else if (a->low >= AC_Q1 && a->high < AC_Q3) {
            a->value -= AC_Q1; a->low -= AC_Q1; a->high -= AC_Q1;
        } else {
            break;
        }
        a->low = 2 * a->low;
        a->high = 2 * a->high + 1;
        a->value = 2 * a->value + arith_bit(d, a);
    }
    model_update(d, m, k - 1);
    return m->lo + k - 1;
}

/* ---------------------------------------------------------------- output rows */
static fba_frame *new_row(dec *d, int64_t fn, double t, int intra, int64_t offset)
{
    if (d->n >= FBA_MAX_FRAMES)
        fail(d, offset, "too-many-frames", "more than %d frames", FBA_MAX_FRAMES);
    if (fn > INT32_MAX)
        fail(d, offset, "frame-number-overflow", "frame number above 2^31-1");
    if (d->n == d->cap) {
        size_t nc = d->cap ? d->cap * 2 : 64;
        fba_frame *f = realloc(d->frames, nc * sizeof *f);
        if (!f) fail(d, offset, "out-of-memory", "cannot grow the frame table");
        d->frames = f;
        d->cap = nc;
    }
    fba_frame *r = &d->frames[d->n++];
    memset(r, 0, sizeof *r);
    r->frame_number = fn;
    r->time_ms = t;
    r->is_intra = intra;
    r->fap_quant = d->fap_quant;
    r->coding_type = d->coding_type;
    r->bit_offset = offset;
    return r;
}

/* Statuses (D3) and the values of FAPs this plane did not code. Coded FAPs' values and
 * high-level fields must already be in the row. */
static void finish_row(dec *d, fba_frame *r)
{
    for (int g = 0; g < 10; g++) {
        for (int j = 0; j < GROUP_SIZE[g]; j++) {
            int i = GROUP_FIRST[g] + j;
            if (d->coded[i]) {
                r->status[i] = FBA_SET;
                d->ever_set[i] = 1;
                continue;
            }
            int st = (d->mask_type[g] != 2 && d->ever_set[i]) ? FBA_RETAINED : FBA_FREE;
            r->status[i] = (uint8_t)st;
            if (i >= 2) {
                r->value[i] = st == FBA_RETAINED ? d->last[i] : 0;
            } else {
                int from = i == 0 ? 0 : 4, cnt = i == 0 ? 4 : 6;
                for (int k = 0; k < cnt; k++)
                    r->high[from + k] = st == FBA_RETAINED ? d->hl[from + k] : 0;
            }
        }
    }
}

static int32_t checked32(dec *d, int64_t v, int fap, int64_t at)
{
    if (v < INT32_MIN || v > INT32_MAX)
        fail(d, at, "value-overflow", "FAP %d value %lld outside int32", fap, (long long)v);
    return (int32_t)v;
}

/* ---------------------------------------------------------------- frame-based planes (§1.3) */
static int32_t hl_step(dec *d, int32_t prev, int32_t diff, int32_t lo, int32_t hi,
                       const char *rule, const char *what, int64_t at)
{
    int64_t v = (int64_t)prev + diff;
    if (v < lo || v > hi)
        fail(d, at, rule, "%s %lld outside %d..%d", what, (long long)v, (int)lo, (int)hi);
    return (int32_t)v;
}

static void arith_plane(dec *d, int intra, size_t row)
{
    int q = d->fap_quant, qd = q ? q : 1;
    int32_t bmax = (q ? (63 + q / 2) / q : 63) * qd; /* largest blend / intensity (D5) */
    int t = intra ? 0 : 1;
    int32_t *hl = d->hl;
    arith a;
    if (d->coded[0]) {
        int64_t at = d->pos;
        arith_start(d, &a);
        int s1 = arith_decode(d, &a, &d->hm[t][HM_VS1]);
        int s2 = arith_decode(d, &a, &d->hm[t][HM_VS2]);
        int b = arith_decode(d, &a, &d->hm[t][HM_VB]);
        arith_end(d, &a);
        if (intra) {
            hl[0] = s1; hl[1] = s2; hl[2] = b * qd;
        } else {
            hl[0] = hl_step(d, hl[0], s1, 0, 14, "viseme-select-range", "viseme_select1", at);
            hl[1] = hl_step(d, hl[1], s2, 0, 14, "viseme-select-range", "viseme_select2", at);
            hl[2] = hl_step(d, hl[2], b * qd, 0, bmax, "blend-range", "viseme_blend", at);
        }
        hl[3] = (int32_t)bits(d, 1, "viseme_def");
    }
    if (d->coded[1]) {
        int64_t at = d->pos;
        arith_start(d, &a);
        int v[4];
        for (int k = 0; k < 4; k++) v[k] = arith_decode(d, &a, &d->hm[t][HM_ES1 + k]);
        arith_end(d, &a);
        if (intra) {
            hl[4] = v[0]; hl[5] = v[1] * qd; hl[6] = v[2]; hl[7] = v[3] * qd;
        } else {
            hl[4] = hl_step(d, hl[4], v[0], 0, 6, "expression-select-range", "expression_select1", at);
            hl[5] = hl_step(d, hl[5], v[1] * qd, 0, bmax, "intensity-range", "expression_intensity1", at);
            hl[6] = hl_step(d, hl[6], v[2], 0, 6, "expression-select-range", "expression_select2", at);
            hl[7] = hl_step(d, hl[7], v[3] * qd, 0, bmax, "intensity-range", "expression_intensity2", at);
        }
        hl[8] = (int32_t)bits(d, 1, "init_face");
        hl[9] = (int32_t)bits(d, 1, "expression_def");
    }
    /* low-level FAPs: always one block, possibly empty */
    int64_t at = d->pos;
    arith_start(d, &a);
    for (int i = 2; i < FBA_NFAP; i++) {
        if (!d->coded[i]) continue;
        int64_t s = arith_decode(d, &a, &d->lm[t][i]);
        int64_t step = q ? (int64_t)FAP_QP[i] * q : 1;
        int64_t v = intra ? s * step : d->last[i] + s * step;
        d->last[i] = checked32(d, v, i + 1, at);
    }
    arith_end(d, &a);
    fba_frame *r = &d->frames[row];
    for (int i = 2; i < FBA_NFAP; i++)
        if (d->coded[i]) r->value[i] = d->last[i];
    if (d->coded[0]) memcpy(r->high, hl, 4 * sizeof *hl);
    if (d->coded[1]) memcpy(r->high + 4, hl + 4, 6 * sizeof *hl);
}

/* ---------------------------------------------------------------- DCT segment mode */
/* Payload bit with the DCT mode's own emulation prevention: a '1' follows every 22nd
 * consecutive '0', the run counted from the last '1' in the stream. */
static int pbit(dec *d, int *zrun)
{
    int b = (int)bits(d, 1, "a DCT plane group");
    if (b) {
        *zrun = 0;
    } else if (++*zrun >= AC_STUFF_RUN) {
        int64_t at = d->pos;
        if (!bits(d, 1, "a DCT plane group"))
            fail(d, at, "dct-stuffing", "stuffing bit after 22 zeros is 0");
        *zrun = 0;
    }
    return b;
}

static uint32_t pbits(dec *d, int *zrun, int n)
{
    uint32_t v = 0;
    for (int i = 0; i < n; i++) v = (v << 1) | (uint32_t)pbit(d, zrun);
    return v;
}

static int32_t psigned(dec *d, int *zrun, int n)
{
    int32_t v = (int32_t)pbits(d, zrun, n);
    return v >= (1 << (n - 1)) ? v - (1 << n) : v;
}

/* Signed Exp-Golomb code of order k (dct_provisional.toml [dc]). */
static int64_t exp_golomb(dec *d, int *zrun, int k)
{
    int64_t at = d->pos;
    int z = 0;
    while (!pbit(d, zrun))
        if (++z > 24) fail(d, at, "invalid-vlc", "Exp-Golomb prefix longer than 24 zeros");
    int64_t info = pbits(d, zrun, z + k);
    int64_t n = ((int64_t)1 << (z + k)) + info - ((int64_t)1 << k);
    return (n & 1) ? (n + 1) / 2 : -(n / 2);
}

/* One AC event; returns 0 for EOB. */
static int ac_event(dec *d, int *zrun, int *run, int *level)
{
    int64_t at = d->pos;
    uint32_t code = 0;
    for (int len = 1; len <= 14; len++) {
        code = (code << 1) | (uint32_t)pbit(d, zrun);
        if (len == 1 && code == 0) return 0; /* EOB '0' */
        if (len == AC_ESCAPE_LEN && code == AC_ESCAPE_CODE) {
            *run = (int)pbits(d, zrun, 4);
            *level = (int)pbits(d, zrun, 14);
            if (!*level) fail(d, at, "invalid-vlc", "escape with level 0");
            if (pbit(d, zrun)) *level = -*level;
            return 1;
        }
        for (size_t e = 0; e < sizeof AC_TABLE / sizeof AC_TABLE[0]; e++) {
            if (AC_TABLE[e].len == len && AC_TABLE[e].code == code) {
                *run = AC_TABLE[e].run;
                *level = AC_TABLE[e].level;
                if (pbit(d, zrun)) *level = -*level;
                return 1;
            }
        }
    }
    fail(d, at, "invalid-vlc", "no AC codeword matches");
    return 0;
}

static int64_t rdiv(int64_t a, int64_t b)
{
    return a >= 0 ? (a + b / 2) / b : -((-a + b / 2) / b);
}

static void dct_high(dec *d, int *zrun, int intra, size_t base, int L)
{
    int32_t *hl = d->hl;
    for (int pass = 0; pass < 2; pass++) {
        if (!d->coded[pass]) continue;
        for (int j = 0; j < L; j++) {
            int64_t at = d->pos;
            if (intra && j == 0) {
                if (pass == 0) {
                    int32_t s1 = (int32_t)pbits(d, zrun, 4), s2 = (int32_t)pbits(d, zrun, 4);
                    hl[2] = (int32_t)pbits(d, zrun, 6);
                    hl[3] = pbit(d, zrun);
                    hl[0] = hl_step(d, 0, s1, 0, 14, "viseme-select-range", "viseme_select1", at);
                    hl[1] = hl_step(d, 0, s2, 0, 14, "viseme-select-range", "viseme_select2", at);
                } else {
                    int32_t s1 = (int32_t)pbits(d, zrun, 3);
                    hl[5] = (int32_t)pbits(d, zrun, 6);
                    int32_t s2 = (int32_t)pbits(d, zrun, 3);
                    hl[7] = (int32_t)pbits(d, zrun, 6);
                    hl[8] = pbit(d, zrun);
                    hl[9] = pbit(d, zrun);
                    hl[4] = hl_step(d, 0, s1, 0, 6, "expression-select-range", "expression_select1", at);
                    hl[6] = hl_step(d, 0, s2, 0, 6, "expression-select-range", "expression_select2", at);
                }
            } else if (!pbit(d, zrun)) { /* 0: differences follow; 1: repeat */
                if (pass == 0) {
                    int32_t d1 = psigned(d, zrun, 5), d2 = psigned(d, zrun, 5), db = psigned(d, zrun, 7);
                    hl[3] = pbit(d, zrun);
                    hl[0] = hl_step(d, hl[0], d1, 0, 14, "viseme-select-range", "viseme_select1", at);
                    hl[1] = hl_step(d, hl[1], d2, 0, 14, "viseme-select-range", "viseme_select2", at);
                    hl[2] = hl_step(d, hl[2], db, 0, 63, "blend-range", "viseme_blend", at);
                } else {
                    int32_t e1 = psigned(d, zrun, 4), i1 = psigned(d, zrun, 7);
                    int32_t e2 = psigned(d, zrun, 4), i2 = psigned(d, zrun, 7);
                    hl[8] = pbit(d, zrun);
                    hl[9] = pbit(d, zrun);
                    hl[4] = hl_step(d, hl[4], e1, 0, 6, "expression-select-range", "expression_select1", at);
                    hl[5] = hl_step(d, hl[5], i1, 0, 63, "intensity-range", "expression_intensity1", at);
                    hl[6] = hl_step(d, hl[6], e2, 0, 6, "expression-select-range", "expression_select2", at);
                    hl[7] = hl_step(d, hl[7], i2, 0, 63, "intensity-range", "expression_intensity2", at);
                }
            }
            if (pass == 0) memcpy(d->frames[base + j].high, hl, 4 * sizeof *hl);
            else memcpy(d->frames[base + j].high + 4, hl + 4, 6 * sizeof *hl);
        }
    }
}

static void dct_group(dec *d, int intra, int64_t offset, int64_t fn0, double t0)
{
    /* zero run entering the payload: counted back to the last '1' of the stream */
    int zrun = 0;
    while (zrun < AC_STUFF_RUN && d->pos - 1 - zrun >= 0 && !raw_bit(d, d->pos - 1 - zrun)) zrun++;
    int L = (int)pbits(d, &zrun, 4) + 1;
    size_t base = d->n;
    for (int j = 0; j < L; j++)
        new_row(d, fn0 + j, t0 + j * 1000.0 / d->rate, intra && j == 0, offset);
    dct_high(d, &zrun, intra, base, L);
    for (int i = 2; i < FBA_NFAP; i++) {
        if (!d->coded[i]) continue;
        int64_t at = d->pos;
        int64_t lev = intra ? exp_golomb(d, &zrun, 3) : d->dc_prev[i] + exp_golomb(d, &zrun, 2);
        if (lev > DC_MAX_LEVEL || lev < -DC_MAX_LEVEL)
            fail(d, at, "coefficient-overflow", "FAP %d DC level %lld", i + 1, (long long)lev);
        d->dc_prev[i] = (int32_t)lev;
        int64_t coef[16] = {lev};
        for (int k = 1;;) {
            int run, level;
            int64_t ev = d->pos;
            if (!ac_event(d, &zrun, &run, &level)) break;
            k += run;
            if (k > 15) fail(d, ev, "run-overflow", "FAP %d AC run past coefficient 15", i + 1);
            coef[k++] = level;
        }
        int64_t delta = (int64_t)FAP_QP[i] * DCT_SCALE[d->fap_quant & 31];
        int64_t y[16];
        y[0] = coef[0] * delta;
        for (int k = 1; k < 16; k++) y[k] = coef[k] * delta * 4;
        for (int n = 0; n < L; n++) {
            int64_t s = 0;
            for (int k = 0; k < 16; k++) s += (int64_t)DCT_M[k][n] * y[k];
            d->last[i] = checked32(d, rdiv(s, (int64_t)1 << 16), i + 1, at);
            d->frames[base + n].value[i] = d->last[i];
        }
    }
    if (zrun >= 20) { /* a payload ending in 20 or more zeros gets a final '1' */
        int64_t at = d->pos;
        if (!bits(d, 1, "a DCT plane group"))
            fail(d, at, "dct-stuffing", "final stuffing bit is 0");
    }
    for (int j = 0; j < L; j++) finish_row(d, &d->frames[base + j]);
    d->prev_fn = fn0 + L - 1;
    d->prev_time = d->frames[base + L - 1].time_ms;
}

/* ---------------------------------------------------------------- plane header (§1.2) */
static void intra_header(dec *d)
{
    d->fap_quant = (int)bits(d, 5, "fap_quant");
    memset(d->coded, 0, sizeof d->coded);
    for (int g = 0; g < 10; g++) {
        marker(d, "mask marker_bit");
        int type = (int)bits(d, 2, "fap_mask_type");
        d->mask_type[g] = type;
        for (int j = 0; j < GROUP_SIZE[g]; j++) {
            int i = GROUP_FIRST[g] + j;
            if (type == 1 || type == 2) d->coded[i] = (uint8_t)bits(d, 1, "FAP mask");
            else d->coded[i] = type == 3;
        }
    }
    int gender = (int)bits(d, 1, "suggested_gender");
    if (d->gender < 0) d->gender = gender;
    d->coding_type = (int)bits(d, 1, "coding_type");
    if (d->coding_type != 0) return;

    /* new min/max lists (§1.4), order I max, I min, P max, P min */
    int flag[4];
    for (int l = 0; l < 4; l++) flag[l] = (int)bits(d, 1, "is_new_min/max");
    for (int l = 0; l < 4; l++) {
        if (!flag[l]) continue;
        for (int g = 1; g < 10; g++) {
            for (int j = 0; j < GROUP_SIZE[g]; j++) {
                int i = GROUP_FIRST[g] + j;
                if (j % 4 == 0) marker(d, "min/max marker_bit");
                if (d->coded[i]) d->bound[l][i] = (int32_t)bits(d, 5, "min/max value") * 60;
            }
        }
    }
    /* (re)initialise the models of the coded FAPs (§3.2, D4, D5) */
    int q = d->fap_quant ? d->fap_quant : 1;
    for (int i = 2; i < FBA_NFAP; i++) {
        if (!d->coded[i]) continue;
        model_init(&d->lm[0][i], -(d->bound[1][i] / q), d->bound[0][i] / q);
        model_init(&d->lm[1][i], -(d->bound[3][i] / q), d->bound[2][i] / q);
    }
    int B = d->fap_quant ? (63 + d->fap_quant / 2) / d->fap_quant : 63;
    static const int hl_max[HM_COUNT] = {14, 14, -1, 6, -1, 6, -1};
    for (int k = 0; k < HM_COUNT; k++) {
        if (!d->coded[k < HM_ES1 ? 0 : 1]) continue;
        int m = hl_max[k] < 0 ? B : hl_max[k];
        model_init(&d->hm[0][k], 0, m);
        model_init(&d->hm[1][k], -m, m);
    }
}

static void parse_plane(dec *d)
{
    int64_t offset = d->pos;
    int intra = (int)bits(d, 1, "is_intra");
    if (d->n_planes == 0 && !intra)
        fail(d, offset, "first-predicted", "the first plane is predicted (D2)");
    int64_t at = d->pos;
    int om = (int)bits(d, 2, "fba_object_mask");
    if (om != 1)
        fail(d, at, "object-mask", "fba_object_mask %d%d, a face stream has 01 (D1)", om >> 1, om & 1);
    double tc_ms = -1;
    if (intra) {
        if (bits(d, 1, "is_frame_rate")) {
            at = d->pos;
            int fr = (int)bits(d, 8, "frame_rate");
            int sec = (int)bits(d, 4, "seconds");
            int fo = (int)bits(d, 1, "frequency_offset");
            double r = fr + sec / 16.0;
            if (fo) r = r * 1000.0 / 1001.0;
            if (!(r > 0)) fail(d, at, "frame-rate-zero", "frame rate 0");
            d->rate = r;
            if (!d->rate_seen) d->first_rate = r;
            d->rate_seen = 1;
        }
        if (bits(d, 1, "is_time_code")) {
            at = d->pos;
            int h = (int)bits(d, 5, "time code hours");
            int m = (int)bits(d, 6, "time code minutes");
            marker(d, "time code marker_bit");
            int s = (int)bits(d, 6, "time code seconds");
            if (h > 23 || m > 59 || s > 59)
                fail(d, at, "time-code-range", "time code %d:%d:%d out of range", h, m, s);
            tc_ms = (3600.0 * h + 60.0 * m + s) * 1000.0;
        }
    }
    int64_t skip = 0;
    if (bits(d, 1, "skip_frames")) {
        uint32_t v;
        do {
            v = bits(d, 4, "number_of_frames_to_skip");
            skip += v;
        } while (v == 15);
    }
    int64_t fn = d->n_planes ? d->prev_fn + skip + 1 : skip;
    double t = tc_ms >= 0 ? tc_ms
             : d->n_planes ? d->prev_time + (double)(skip + 1) * 1000.0 / d->rate
                           : (double)skip * 1000.0 / d->rate;
    if (intra) intra_header(d);
    d->n_planes++;
    if (d->coding_type == 1) {
        dct_group(d, intra, offset, fn, t);
        return;
    }
    size_t row = d->n;
    new_row(d, fn, t, intra, offset);
    arith_plane(d, intra, row);
    finish_row(d, &d->frames[row]);
    d->prev_fn = fn;
    d->prev_time = t;
}

/* ---------------------------------------------------------------- object level (§1.1, D1, D9) */
static int is_prefix(const dec *d, size_t k)
{
    return k + 3 < d->len && d->buf[k] == 0 && d->buf[k + 1] == 0 && d->buf[k + 2] == 1;
}

/* If next_start_code() stuffing and a start code follow at bit p, return the start code's
 * byte offset; else -1. The stuffing is required: at an aligned position it is the byte 0x7F
 * (D1; resolved after the differential run with the reference, see NOTES.md). */
static int64_t start_code_at(const dec *d, int64_t p)
{
    if ((p & 7) == 0) {
        size_t k = (size_t)(p >> 3);
        if (k < d->len && d->buf[k] == 0x7F && is_prefix(d, k + 1)) return (int64_t)k + 1;
        return -1;
    }
    if (raw_bit(d, p)) return -1;
    for (int64_t q = p + 1; q & 7; q++)
        if (!raw_bit(d, q)) return -1;
    size_t k = (size_t)((p + 7) >> 3);
    return is_prefix(d, k) ? (int64_t)k : -1;
}

/* End of the data without an end code: nothing left, or fewer than 8 zero bits (the last
 * byte's padding: a plane's fba_object_mask 01 is never zero). Any other tail begins a plane
 * (resolved after the differential run with the reference, see NOTES.md). */
static int at_data_end(const dec *d, int64_t p)
{
    int64_t rem = d->nbits - p;
    if (rem <= 0) return 1;
    if (rem >= 8) return 0;
    for (int64_t q = p; q < d->nbits; q++)
        if (raw_bit(d, q)) return 0;
    return 1;
}

static void add_start_code(dec *d, int64_t k)
{
    if (d->nsc == d->capsc) {
        size_t nc = d->capsc ? d->capsc * 2 : 16;
        int64_t *s = realloc(d->sc, nc * sizeof *s);
        if (!s) fail(d, k * 8, "out-of-memory", "cannot grow the start code table");
        d->sc = s;
        d->capsc = nc;
    }
    d->sc[d->nsc++] = k;
}

/* D9: a byte-aligned 0x000001 before bit `limit` that is not a start code we consumed. */
static int64_t find_emulation(const dec *d, int64_t limit)
{
    size_t next = 0;
    for (size_t b = 0; b + 2 < d->len && (int64_t)b * 8 < limit; b++) {
        if (d->buf[b] != 0 || d->buf[b + 1] != 0 || d->buf[b + 2] != 1) continue;
        while (next < d->nsc && d->sc[next] < (int64_t)b) next++;
        if (next < d->nsc && d->sc[next] == (int64_t)b) continue;
        return (int64_t)b * 8;
    }
    return -1;
}

static void decode_object(dec *d, int64_t *end_bits)
{
    if (d->len < 4)
        fail(d, 0, "too-short", "%zu bytes, not even a start code", d->len);
    if (d->len > MAX_INPUT_BYTES)
        fail(d, 0, "too-large", "stream larger than %u bytes", MAX_INPUT_BYTES);
    if (!is_prefix(d, 0) || d->buf[3] != 0xBA)
        fail(d, 0, "not-face", "the stream does not start with face_object_start_code 0x000001BA");
    add_start_code(d, 0);
    d->pos = 32;
    *end_bits = d->nbits;
    for (;;) {
        int64_t k = start_code_at(d, d->pos);
        if (k >= 0) {
            uint8_t code = d->buf[k + 3];
            if (code == 0xBB) {
                add_start_code(d, k);
                d->pos = (k + 4) * 8;
                parse_plane(d);
                continue;
            }
            if (code == 0xB1) {
                add_start_code(d, k);
                *end_bits = (k + 4) * 8;
                break;
            }
            fail(d, k * 8, "unexpected-start-code", "start code 0x000001%02X inside the face object", code);
        }
        if (at_data_end(d, d->pos)) break;
        parse_plane(d);
    }
    if (d->n_planes == 0)
        fail(d, d->pos, "no-planes", "the face object holds no plane");
}

int fba_decode(const uint8_t *data, size_t len, fba_result *res, fba_error *err)
{
    memset(res, 0, sizeof *res);
    memset(err, 0, sizeof *err);
    dec *d = calloc(1, sizeof *d);
    if (!d) {
        err->rule = "out-of-memory";
        snprintf(err->message, sizeof err->message, "cannot allocate the decoder");
        return -1;
    }
    d->buf = data;
    d->len = len;
    d->nbits = (int64_t)len * 8;
    d->err = err;
    d->rate = 25.0;
    d->gender = -1;
    for (int i = 2; i < FBA_NFAP; i++) { /* D4: defaults rounded away from zero to 60 */
        int32_t ir = (FAP_IRANGE[i] + 59) / 60 * 60, pr = (FAP_PRANGE[i] + 59) / 60 * 60;
        d->bound[0][i] = d->bound[1][i] = ir;
        d->bound[2][i] = d->bound[3][i] = pr;
    }
    volatile int ok = 0;
    int64_t end_bits = d->nbits;
    if (setjmp(d->jb) == 0) {
        decode_object(d, &end_bits);
        int64_t em = find_emulation(d, end_bits);
        if (em >= 0)
            fail(d, em, "start-code-emulation", "byte-aligned 0x000001 that is not a start code (D9)");
        ok = 1;
    } else {
        /* an emulated start code earlier than the error is the first thing that is wrong */
        int64_t em = find_emulation(d, err->bit_offset);
        if (em >= 0 && em < err->bit_offset && strcmp(err->rule, "start-code-emulation") != 0) {
            err->rule = "start-code-emulation";
            err->bit_offset = em;
            snprintf(err->message, sizeof err->message,
                     "byte-aligned 0x000001 that is not a start code (D9)");
        }
    }
    for (int t = 0; t < 2; t++) {
        for (int i = 0; i < FBA_NFAP; i++) { free(d->lm[t][i].freq); free(d->lm[t][i].tree); }
        for (int k = 0; k < HM_COUNT; k++) { free(d->hm[t][k].freq); free(d->hm[t][k].tree); }
    }
    free(d->sc);
    if (ok) {
        res->frames = d->frames;
        res->n_frames = d->n;
        res->frame_rate = d->rate_seen ? d->first_rate : 25.0;
        res->gender = d->gender < 0 ? 0 : d->gender;
    } else {
        free(d->frames);
    }
    free(d);
    return ok ? 0 : -1;
}

void fba_result_free(fba_result *res)
{
    free(res->frames);
    memset(res, 0, sizeof *res);
}
