/* fba_mutator.c - fbaconf's structure-aware mutator of face object streams, for the coverage-guided
 * engines parser authors run: libFuzzer (LLVMFuzzerCustomMutator / LLVMFuzzerCustomCrossOver: built
 * with -DFBA_LIBFUZZER on its own, uninstrumented, and linked into the fuzz target), AFL++ (the
 * custom-mutator API, built with -DFBA_AFL as a shared library for AFL_CUSTOM_MUTATOR_LIBRARY) and
 * fbaconf's own engine (fuzz/cmutator.py loads it through ctypes: fba_mutate, fba_cross, and
 * fba_rewrite / fba_edit_symbol for tools and tests). Written by `fbaconf fuzz export`.
 *
 * Byte-level havoc breaks a face object stream at once: its planes are bit-packed headers followed by
 * adaptive arithmetic-coded blocks, and a plane without a start code of its own starts where the
 * previous plane's last block ends. So this mutator does what a decoder does and then what an encoder
 * does (spec notes §1 and §3, decisions D1-D9):
 *
 *   parse    the stream into planes (start code or not, every header field, the symbols of the
 *            viseme, expression and low-level blocks decoded with the adaptive models, a DCT
 *            group's payload), as far as it decodes; what follows an error is kept as raw bits;
 *   mutate   that structure: a symbol value (its alphabet's ends, +/-1, random), a header field
 *            (frame rate, time code, skip count, fap_quant, masks, gender, min/max lists, the
 *            is_* flags, intra/predicted), whole planes (drop, duplicate, swap, start code on or
 *            off or changed to another code), the end code, a DCT group's events, DC, length and
 *            high-level fields, many fields of one plane at an end at once; crossover joins the
 *            planes of two streams;
 *   write    it back: every header field, every block re-encoded through the arithmetic coder with
 *            models evolving as the decoder's do, symbols kept inside the alphabet the (mutated)
 *            header gives them, next_start_code() stuffing recomputed, the raw tail appended.
 *
 * So a mutation that should keep the stream valid does (a new fap_quant or list re-encodes every
 * symbol it affects; a mask change adds or drops symbols), and the decoder's deep code is reached.
 * A few mutations break one thing on purpose: a field written in place after the write (markers,
 * reserved values), a predicted high-level difference taken out of range, truncation at a
 * structure boundary. */
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#define NFAP 68
#define NHM 7          /* viseme select 1, 2, blend; expression select 1, intensity 1, select 2, intensity 2 */
#define NSYM (NHM + NFAP - 2) /* a plane's symbols: the NHM high-level ones, then low-level FAPs 3..68 */
#define MAX_PLANES 4096
#define MAX_SKIP 1000000u
#define STUFF_RUN 22
#define TOP 65535u
#define Q1 16384u
#define Q2 32768u
#define Q3 49152u
#define MAXFREQ 16383

static const int GROUP_FIRST[10] = {0, 2, 18, 30, 38, 42, 47, 50, 60, 64};
static const int GROUP_SIZE[10] = {2, 16, 12, 8, 4, 5, 3, 10, 4, 4};
/* default quantiser ranges (D4), FAPs 1..68 */
static const int16_t IRANGE[NFAP] = {0, 0, 1080, 600, 1860, 600, 600, 600, 600, 1860, 1860, 600, 600, 600, 1080, 1080, 1080, 420, 1080, 1080, 600, 600, 1200, 1200, 900, 900, 600, 600, 420, 420, 900, 900, 900, 900, 900, 900, 900, 900, 900, 900, 600, 600, 1080, 1080, 1080, 1080, 1080, 1860, 1860, 1860, 600, 1860, 600, 600, 600, 600, 1860, 1860, 600, 600, 540, 540, 680, 900, 900, 900, 900, 900};
static const int16_t PRANGE[NFAP] = {0, 0, 360, 180, 600, 180, 180, 180, 180, 600, 600, 180, 180, 180, 360, 360, 360, 180, 600, 600, 240, 240, 420, 420, 300, 300, 180, 180, 120, 120, 360, 360, 360, 360, 360, 360, 300, 300, 300, 300, 180, 180, 420, 420, 420, 420, 420, 600, 600, 600, 180, 600, 180, 180, 180, 180, 600, 600, 180, 180, 120, 120, 180, 180, 240, 240, 300, 300};
static const int HL_MAX[NHM] = {14, 14, -1, 6, -1, 6, -1}; /* -1: the blend/intensity bound of fap_quant (D5) */

/* The DCT segment mode's AC codewords, {run, |level|, length, code}: bitstreams/data/dct_provisional.toml
 * [ac] (provisional: fbaconf's choice, not the normative table; tests/integration/test_fuzz_mutator.py
 * holds this copy to the file). Escape: the 9-bit code, the run (4 bits), |level| (14 bits), the sign. */
struct ac_code { uint8_t run, level, len; uint16_t code; };
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
#define AC_ESCAPE_LEN 9
#define AC_ESCAPE_CODE 0x1EC
#define AC_MAX_LEVEL 16383
#define DCT_LEN 16

/* ---------------------------------------------------------------- random numbers */
typedef struct { uint64_t s; } fba_rng;

static uint32_t fba_rand(fba_rng *r)
{
    r->s ^= r->s << 13;
    r->s ^= r->s >> 7;
    r->s ^= r->s << 17;
    return (uint32_t)(r->s >> 11);
}

static uint32_t below(fba_rng *r, uint32_t n) { return n ? fba_rand(r) % n : 0; }

/* ---------------------------------------------------------------- the structure */
typedef struct {
    uint8_t sc, sc_code;                /* a start code before the plane (next_start_code stuffing first), its last byte */
    uint8_t intra, om;
    uint8_t is_fr, fr, sec, fo;
    uint8_t is_tc, h, m, s;
    uint8_t skip_flag;
    uint32_t skip;
    /* intra header (a predicted plane keeps its period's, for a flip to intra) */
    uint8_t q, mtype[10], mbit[NFAP], gender, coding, lflag[4], lval[4][NFAP];
    /* the values its blocks code (intra: the value; predicted: the difference), in NSYM order */
    int32_t sym[NSYM];
    uint8_t vdef, initf, edef;
    int32_t dct;                        /* a DCT plane group's payload: its index in the stream's pool, or -1 */
} plane;

/* A DCT plane group's payload (dct_provisional.toml): its length, the high-level fields of each frame
 * (per pass, viseme then expression: a repeat flag and the fields as written, unsigned), and per FAP
 * the DC value as coded (an intra group's level, a predicted one's difference) and the AC events. */
typedef struct {
    uint8_t len1;                       /* segment_length_minus1 */
    uint8_t rep[2][DCT_LEN];            /* 1: the frame repeats the high-level values (not for an intra group's first) */
    uint16_t hv[2][DCT_LEN][6];
    int32_t dc[NFAP];
    uint8_t nev[NFAP], run[NFAP][DCT_LEN - 1];
    int16_t lev[NFAP][DCT_LEN - 1];
} dctdata;

typedef struct {
    plane *p;
    size_t n, cap;
    int end_code;          /* the object ended with visual_object_sequence_end_code */
    int64_t post_bit, post_end; /* raw bits after the end code (of `tail`) */
    const uint8_t *tail;   /* raw bits kept after the planes: [tail_bit, tail_end) of `tail` */
    int64_t tail_bit, tail_end;
    dctdata *dp;           /* the DCT payloads the planes point into */
    size_t ndp, capdp;
} stream;

static int32_t add_dct(stream *st)
{
    if (st->ndp == st->capdp) {
        size_t nc = st->capdp ? st->capdp * 2 : 4;
        dctdata *nd = realloc(st->dp, nc * sizeof *nd);
        if (!nd) return -1;
        st->dp = nd;
        st->capdp = nc;
    }
    memset(&st->dp[st->ndp], 0, sizeof *st->dp);
    return (int32_t)st->ndp++;
}

/* The stream as a fresh one (all zero), keeping its tables of planes and DCT payloads. */
static void stream_clear(stream *st)
{
    plane *p = st->p;
    dctdata *dp = st->dp;
    size_t cap = st->cap, capdp = st->capdp;
    memset(st, 0, sizeof *st);
    st->p = p;
    st->cap = cap;
    st->dp = dp;
    st->capdp = capdp;
}

static plane *add_plane(stream *st)
{
    if (st->n == st->cap) {
        if (st->cap >= MAX_PLANES) return NULL;
        size_t nc = st->cap ? st->cap * 2 : 16;
        plane *np = realloc(st->p, nc * sizeof *np);
        if (!np) return NULL;
        st->p = np;
        st->cap = nc;
    }
    plane *p = &st->p[st->n];
    memset(p, 0, sizeof *p);
    p->dct = -1;
    return p;
}

/* ---------------------------------------------------------------- adaptive models (§3.2) */
/* The model of §3.2: frequencies starting at 1, cum[k] the sum of freq[k..n-1] (descending, cum[0]
 * the total), +1 for the symbol coded, every frequency halved (rounding up) once the total reaches
 * 16383. Kept here as a Fenwick tree of what each frequency has above 1 (extra[k] = freq[k] - 1), so
 * a symbol costs O(log n) and not the O(n) of updating a cumulative table (alphabets reach 3,721
 * symbols: bounds of 31*60 at q = 1), and setting a model up is clearing two arrays, not summing
 * them; a model gets its tree only at its second update, uniform until then but for one symbol (an
 * intra plane's model codes one symbol before the next intra plane sets it up again). Same numbers
 * as the table, faster. */
typedef struct { int n, lo, cap, uniform, one; int32_t total, *extra, *tree; } model;

static void model_init(model *m, int lo, int hi)
{
    m->lo = lo;
    m->n = hi - lo + 1 < 1 ? 1 : hi - lo + 1;
    m->uniform = 1;
    m->one = -1; /* the symbol coded once while uniform (its frequency is 2), or -1 */
    m->total = m->n;
}

static void tree_add(model *m, int k, int32_t d)
{
    for (int i = k + 1; i <= m->n; i += i & -i) m->tree[i] += d;
}

static int32_t prefix(const model *m, int k) /* freq[0] + ... + freq[k-1] */
{
    int32_t t = k;
    for (int i = k; i > 0; i -= i & -i) t += m->tree[i];
    return t;
}

static void tree_build(model *m)
{
    m->tree[0] = 0;
    for (int i = 1; i <= m->n; i++) m->tree[i] = m->extra[i - 1];
    for (int i = 1; i <= m->n; i++) {
        int j = i + (i & -i);
        if (j <= m->n) m->tree[j] += m->tree[i];
    }
}

static int32_t cum(const model *m, int k)
{
    return m->uniform ? m->n - k + (k <= m->one) : m->total - prefix(m, k);
}

/* The first k >= 1 with cum[k] <= target (target < total). */
static int find(const model *m, uint64_t target)
{
    if (m->uniform) {
        int64_t k = (int64_t)m->n - (int64_t)target;
        if (k < 1) k = 1;
        while ((uint64_t)cum(m, (int)k) > target) k++;
        return (int)k;
    }
    /* cum[k] <= target  <=>  prefix(k) >= total - target: the smallest such k, by descending the tree
     * (a node covering `step` symbols holds their extras; their frequencies add `step` more) */
    int32_t need = m->total - (int32_t)target, pos = 0, step = 1;
    while (step * 2 <= m->n) step *= 2;
    for (; step; step /= 2)
        if (pos + step <= m->n && m->tree[pos + step] + step < need) {
            pos += step;
            need -= m->tree[pos] + step;
        }
    return pos + 1 < 1 ? 1 : pos + 1;
}

static int model_update(model *m, int s)
{
    if (m->uniform && m->one < 0) {
        m->one = s;
        m->total++;
        return 0;
    }
    if (m->uniform) {
        if (m->n > m->cap) {
            int32_t *f = realloc(m->extra, (size_t)m->n * sizeof *f), *t;
            if (!f) return -1;
            m->extra = f;
            t = realloc(m->tree, (size_t)(m->n + 1) * sizeof *t);
            if (!t) return -1;
            m->tree = t;
            m->cap = m->n;
        }
        memset(m->extra, 0, (size_t)m->n * sizeof *m->extra);
        memset(m->tree, 0, (size_t)(m->n + 1) * sizeof *m->tree);
        m->extra[m->one] = 1;
        tree_add(m, m->one, 1);
        m->uniform = 0;
    }
    if (m->total >= MAXFREQ) { /* (1 + e + 1) / 2 = 1 + e / 2 */
        m->total = m->n;
        for (int k = 0; k < m->n; k++) {
            m->extra[k] >>= 1;
            m->total += m->extra[k];
        }
        tree_build(m);
    }
    m->extra[s]++;
    m->total++;
    tree_add(m, s, 1);
    return 0;
}

/* The coding state both directions share: the current period's header, the bounds and the models. */
typedef struct {
    int q, mtype[10];
    uint8_t coded[NFAP];
    int32_t bound[4][NFAP]; /* |I max|, |I min|, |P max|, |P min| in q = 1 units (D4) */
    int32_t hl[10];
    model lm[2][NFAP], hm[2][NHM];
    int planes, coding;
} codec;

static void codec_reset(codec *c)
{
    for (int i = 2; i < NFAP; i++) {
        int32_t ir = (IRANGE[i] + 59) / 60 * 60, pr = (PRANGE[i] + 59) / 60 * 60;
        c->bound[0][i] = c->bound[1][i] = ir;
        c->bound[2][i] = c->bound[3][i] = pr;
    }
    memset(c->coded, 0, sizeof c->coded);
    memset(c->hl, 0, sizeof c->hl);
    c->planes = 0;
    c->coding = 0;
    c->q = 0;
}

/* The codec as a fresh one (all zero), keeping each model's tables for the next stream: a model
 * fills them before it reads them (at its second update). */
static void codec_clear(codec *c)
{
    model lm[2][NFAP], hm[2][NHM];
    memcpy(lm, c->lm, sizeof lm);
    memcpy(hm, c->hm, sizeof hm);
    memset(c, 0, sizeof *c);
    for (int t = 0; t < 2; t++) {
        for (int i = 0; i < NFAP; i++) {
            c->lm[t][i].extra = lm[t][i].extra;
            c->lm[t][i].tree = lm[t][i].tree;
            c->lm[t][i].cap = lm[t][i].cap;
        }
        for (int k = 0; k < NHM; k++) {
            c->hm[t][k].extra = hm[t][k].extra;
            c->hm[t][k].tree = hm[t][k].tree;
            c->hm[t][k].cap = hm[t][k].cap;
        }
    }
    codec_reset(c);
}

static int blend_max(int q) { return q ? (63 + q / 2) / q : 63; }

/* Whether a group's mask type lists its FAPs one by one (01 and 10), and whether FAP i of group g
 * is coded under plane p's mask (§1.2: 00 none, 11 all). */
static int lists_bits(int type) { return type == 1 || type == 2; }

static int coded_in(const plane *p, int g, int i) { return lists_bits(p->mtype[g]) ? p->mbit[i] : p->mtype[g] == 3; }

/* An intra plane's header taken into the state: mask, lists, models re-initialised (§3.2, D4, D5). */
static int codec_intra(codec *c, const plane *p)
{
    c->q = p->q;
    for (int g = 0; g < 10; g++) {
        c->mtype[g] = p->mtype[g];
        for (int j = 0; j < GROUP_SIZE[g]; j++) c->coded[GROUP_FIRST[g] + j] = (uint8_t)coded_in(p, g, GROUP_FIRST[g] + j);
    }
    c->coding = p->coding;
    if (p->coding) return 0;
    for (int l = 0; l < 4; l++)
        if (p->lflag[l])
            for (int i = 2; i < NFAP; i++)
                if (c->coded[i]) c->bound[l][i] = (int32_t)p->lval[l][i] * 60;
    int q = c->q ? c->q : 1;
    for (int i = 2; i < NFAP; i++) {
        if (!c->coded[i]) continue;
        model_init(&c->lm[0][i], -(c->bound[1][i] / q), c->bound[0][i] / q);
        model_init(&c->lm[1][i], -(c->bound[3][i] / q), c->bound[2][i] / q);
    }
    int B = blend_max(c->q);
    for (int k = 0; k < NHM; k++) {
        if (!c->coded[k < 3 ? 0 : 1]) continue;
        int m = HL_MAX[k] < 0 ? B : HL_MAX[k];
        model_init(&c->hm[0][k], 0, m);
        model_init(&c->hm[1][k], -m, m);
    }
    return 0;
}

/* ---------------------------------------------------------------- reading */
typedef struct {
    const uint8_t *d;
    int64_t nbits, pos;
    int bad;                          /* the plane being read does not decode */
} reader;

static int rbit(const reader *r, int64_t p)
{
    return (p >= 0 && p < r->nbits) ? (r->d[p >> 3] >> (7 - (p & 7))) & 1 : 0;
}

static uint32_t rbits(reader *r, int n)
{
    if (r->pos + n > r->nbits) { r->bad = 1; return 0; }
    uint32_t v = 0;
    for (int i = 0; i < n; i++) v = (v << 1) | (uint32_t)rbit(r, r->pos++);
    return v;
}

typedef struct { uint32_t low, high, value; int zrun; int64_t count, ipos[16], bad_at; } adec;

static uint32_t abit(reader *r, adec *a)
{
    int64_t p = r->pos++;
    int b = rbit(r, p);
    a->count++;
    a->ipos[a->count & 15] = p;
    if (a->bad_at >= 0 && a->count >= a->bad_at + 14) r->bad = 1; /* a 0 stuffing bit inside the block (D7) */
    if (b) {
        a->zrun = 0;
    } else if (++a->zrun == STUFF_RUN) {
        a->zrun = 0;
        if (!rbit(r, r->pos++) && a->bad_at < 0) a->bad_at = a->count; /* in the look-ahead it is no error */
    }
    return (uint32_t)b;
}

static void astart(reader *r, adec *a)
{
    memset(a, 0, sizeof *a);
    a->bad_at = -1;
    a->high = TOP;
    for (int i = 0; i < 16; i++) a->value = (a->value << 1) | abit(r, a);
}

static void aend(reader *r, adec *a)
{
    r->pos = a->ipos[(a->count - 13) & 15];
    if (r->pos > r->nbits) r->bad = 1;
}

static int32_t adecode(reader *r, adec *a, model *m)
{
    if (r->bad || a->value < a->low || a->value > a->high) { r->bad = 1; return 0; }
    uint64_t len = (uint64_t)a->high - a->low + 1, c0 = (uint64_t)cum(m, 0);
    uint64_t target = (((uint64_t)a->value - a->low + 1) * c0 - 1) / len;
    int k = find(m, target);
    a->high = (uint32_t)(a->low - 1 + len * (uint64_t)cum(m, k - 1) / c0);
    a->low = (uint32_t)(a->low + len * (uint64_t)cum(m, k) / c0);
    for (;;) {
        if (a->high < Q2) {
        } else if (a->low >= Q2) {
            a->value -= Q2; a->low -= Q2; a->high -= Q2;
        } else if (a->low >= Q1 && a->high < Q3) {
            a->value -= Q1; a->low -= Q1; a->high -= Q1;
        } else {
            break;
        }
        a->low = 2 * a->low;
        a->high = 2 * a->high + 1;
        a->value = 2 * a->value + abit(r, a);
    }
    if (model_update(m, k - 1)) r->bad = 1;
    return m->lo + k - 1;
}

static int is_prefix(const uint8_t *d, size_t n, size_t k)
{
    return k + 3 < n && d[k] == 0 && d[k + 1] == 0 && d[k + 2] == 1;
}

/* next_start_code() stuffing at bit p followed by a start code: the code's byte offset, else -1 (D1). */
static int64_t start_code_at(const reader *r, size_t n, int64_t p)
{
    if ((p & 7) == 0) {
        size_t k = (size_t)(p >> 3);
        return (k < n && r->d[k] == 0x7F && is_prefix(r->d, n, k + 1)) ? (int64_t)k + 1 : -1;
    }
    if (rbit(r, p)) return -1;
    for (int64_t q = p + 1; q & 7; q++)
        if (!rbit(r, q)) return -1;
    size_t k = (size_t)((p + 7) >> 3);
    return is_prefix(r->d, n, k) ? (int64_t)k : -1;
}

static int at_data_end(const reader *r, int64_t p)
{
    int64_t rem = r->nbits - p;
    if (rem <= 0) return 1;
    if (rem >= 8) return 0;
    for (int64_t q = p; q < r->nbits; q++)
        if (rbit(r, q)) return 0;
    return 1;
}

/* ---------------------------------------------------------------- DCT segment payloads */
/* Payload bits carry the DCT mode's own emulation prevention: a '1' after every 22nd consecutive '0',
 * the run counted from the last '1' of the stream (so it starts with the zeros before the payload). */
typedef struct { reader *r; int zrun; } preader;

static int pbit(preader *p)
{
    int b = (int)rbits(p->r, 1);
    if (b) {
        p->zrun = 0;
    } else if (++p->zrun >= STUFF_RUN) {
        if (!rbits(p->r, 1)) p->r->bad = 1;
        p->zrun = 0;
    }
    return b;
}

static uint32_t pbits(preader *p, int n)
{
    uint32_t v = 0;
    for (int i = 0; i < n; i++) v = (v << 1) | (uint32_t)pbit(p);
    return v;
}

/* Signed Exp-Golomb of order k (v > 0 -> 2v-1, v <= 0 -> -2v); a prefix over 24 zeros is invalid. */
static int32_t eg_read(preader *p, int k)
{
    int z = 0;
    while (!p->r->bad && !pbit(p))
        if (++z > 24) { p->r->bad = 1; return 0; }
    int64_t n = ((int64_t)1 << (z + k)) + (int64_t)pbits(p, z + k) - ((int64_t)1 << k);
    return (int32_t)((n & 1) ? (n + 1) / 2 : -(n / 2));
}

/* One AC event: 1 (run, level), 0 end of block, -1 no valid event. */
static int ac_read(preader *p, int *run, int *level)
{
    uint32_t code = 0;
    for (int len = 1; len <= 14 && !p->r->bad; len++) {
        code = (code << 1) | (uint32_t)pbit(p);
        if (len == 1 && code == 0) return 0;
        if (len == AC_ESCAPE_LEN && code == AC_ESCAPE_CODE) {
            *run = (int)pbits(p, 4);
            *level = (int)pbits(p, 14);
            if (pbit(p)) *level = -*level;
            return *level ? 1 : -1;
        }
        for (size_t e = 0; e < sizeof AC_TABLE / sizeof *AC_TABLE; e++)
            if (AC_TABLE[e].len == len && AC_TABLE[e].code == code) {
                *run = AC_TABLE[e].run;
                *level = pbit(p) ? -AC_TABLE[e].level : AC_TABLE[e].level;
                return 1;
            }
    }
    return -1;
}

/* The widths of a DCT group's high-level fields: [pass][first frame of an intra group], 0 ends. */
static const uint8_t HL_WIDTH[2][2][6] = {{{5, 5, 7, 1}, {4, 4, 6, 1}}, {{4, 7, 4, 7, 1, 1}, {3, 6, 3, 6, 1, 1}}};

/* A DCT plane group's payload; 0 when it reads as the decoder reads it. */
static int read_dct(reader *r, const codec *c, int intra, dctdata *dd)
{
    preader p = {r, 0};
    while (p.zrun < STUFF_RUN && r->pos - 1 - p.zrun >= 0 && !rbit(r, r->pos - 1 - p.zrun)) p.zrun++;
    dd->len1 = (uint8_t)pbits(&p, 4);
    for (int pass = 0; pass < 2; pass++) {
        if (!c->coded[pass]) continue;
        for (int j = 0; j <= dd->len1; j++) {
            int first = intra && j == 0;
            if (!first && (dd->rep[pass][j] = (uint8_t)pbit(&p))) continue;
            for (int f = 0; f < 6 && HL_WIDTH[pass][first][f]; f++) dd->hv[pass][j][f] = (uint16_t)pbits(&p, HL_WIDTH[pass][first][f]);
        }
    }
    for (int i = 2; i < NFAP && !r->bad; i++) {
        if (!c->coded[i]) continue;
        dd->dc[i] = eg_read(&p, intra ? 3 : 2);
        int k = 1, n = 0, run, level, e;
        while ((e = ac_read(&p, &run, &level)) > 0) {
            k += run;
            if (k > 15) return -1; /* run-overflow: the decoder's to judge; such a group is kept raw */
            dd->run[i][n] = (uint8_t)run;
            dd->lev[i][n++] = (int16_t)level;
            k++;
        }
        if (e < 0) return -1;
        dd->nev[i] = (uint8_t)n;
    }
    if (p.zrun >= 20 && !rbits(r, 1)) return -1; /* the final stuffing '1' */
    return r->bad ? -1 : 0;
}

/* One plane from r->pos into p (its start code flags already set); 0 when it decoded. */
static int read_plane(reader *r, codec *c, stream *st, plane *p, const plane *period)
{
    p->intra = (uint8_t)rbits(r, 1);
    p->om = (uint8_t)rbits(r, 2);
    if (r->bad || (c->planes == 0 && !p->intra)) return -1;
    if (period) { /* a predicted plane keeps its period's header, values for a flip to intra */
        p->q = period->q;
        memcpy(p->mtype, period->mtype, sizeof p->mtype);
        memcpy(p->mbit, period->mbit, sizeof p->mbit);
        memcpy(p->lval, period->lval, sizeof p->lval);
        p->gender = period->gender;
        p->coding = period->coding;
    }
    p->fr = 25;
    if (p->intra) {
        if ((p->is_fr = (uint8_t)rbits(r, 1))) {
            p->fr = (uint8_t)rbits(r, 8); p->sec = (uint8_t)rbits(r, 4); p->fo = (uint8_t)rbits(r, 1);
        }
        if ((p->is_tc = (uint8_t)rbits(r, 1))) {
            p->h = (uint8_t)rbits(r, 5); p->m = (uint8_t)rbits(r, 6);
            if (!rbits(r, 1)) return -1;
            p->s = (uint8_t)rbits(r, 6); /* values out of range are kept: the decoder under test judges them */
        }
    }
    if ((p->skip_flag = (uint8_t)rbits(r, 1))) {
        uint32_t v;
        do {
            v = rbits(r, 4);
            p->skip += v;
        } while (v == 15 && !r->bad && p->skip < MAX_SKIP);
        if (v == 15) return -1;
    }
    if (r->bad) return -1;
    if (p->intra) {
        p->q = (uint8_t)rbits(r, 5);
        for (int g = 0; g < 10; g++) {
            if (!rbits(r, 1)) return -1;
            p->mtype[g] = (uint8_t)rbits(r, 2);
            for (int j = 0; j < GROUP_SIZE[g]; j++) {
                int i = GROUP_FIRST[g] + j;
                p->mbit[i] = lists_bits(p->mtype[g]) ? (uint8_t)rbits(r, 1) : 1;
            }
        }
        p->gender = (uint8_t)rbits(r, 1);
        p->coding = (uint8_t)rbits(r, 1);
        if (r->bad) return -1;
        for (int i = 2; i < NFAP; i++) /* the lists in force, for a list flag turned on */
            for (int l = 0; l < 4; l++) p->lval[l][i] = (uint8_t)(c->bound[l][i] / 60 > 31 ? 31 : c->bound[l][i] / 60);
        if (!p->coding) {
            for (int l = 0; l < 4; l++) p->lflag[l] = (uint8_t)rbits(r, 1);
            for (int l = 0; l < 4; l++) {
                if (!p->lflag[l]) continue;
                for (int g = 1; g < 10; g++)
                    for (int j = 0; j < GROUP_SIZE[g]; j++) {
                        int i = GROUP_FIRST[g] + j;
                        if (j % 4 == 0 && !rbits(r, 1)) return -1;
                        if (coded_in(p, g, i)) p->lval[l][i] = (uint8_t)rbits(r, 5);
                    }
            }
        }
        if (r->bad || codec_intra(c, p)) return -1;
    }
    c->planes++;
    if (c->coding) {
        int32_t at = add_dct(st);
        if (at < 0 || read_dct(r, c, p->intra, &st->dp[at])) return -1;
        p->dct = at;
        return 0;
    }
    int t = p->intra ? 0 : 1;
    adec a;
    if (c->coded[0]) {
        astart(r, &a);
        for (int k = 0; k < 3; k++) p->sym[k] = adecode(r, &a, &c->hm[t][k]);
        aend(r, &a);
        p->vdef = (uint8_t)rbits(r, 1);
    }
    if (c->coded[1]) {
        astart(r, &a);
        for (int k = 3; k < NHM; k++) p->sym[k] = adecode(r, &a, &c->hm[t][k]);
        aend(r, &a);
        p->initf = (uint8_t)rbits(r, 1);
        p->edef = (uint8_t)rbits(r, 1);
    }
    astart(r, &a);
    for (int i = 2; i < NFAP; i++)
        if (c->coded[i]) p->sym[NHM + i - 2] = adecode(r, &a, &c->lm[t][i]);
    aend(r, &a);
    return r->bad ? -1 : 0;
}

/* The stream's structure; 0 when it is not a face object stream at all. */
static int parse(const uint8_t *d, size_t n, stream *st, codec *c)
{
    stream_clear(st);
    if (n < 4 || !is_prefix(d, n, 0) || d[3] != 0xBA) return 0;
    reader r = {d, (int64_t)n * 8, 32, 0};
    codec_clear(c);
    const plane *period = NULL;
    size_t period_at = 0;
    st->tail = d;
    st->tail_bit = st->tail_end = r.nbits;
    for (;;) {
        int64_t at = r.pos, k = start_code_at(&r, n, r.pos);
        uint8_t sc = 0, code = 0;
        if (k >= 0) {
            code = d[k + 3];
            if (code == 0xB1) {
                st->end_code = 1;
                st->tail_bit = st->tail_end = at;
                st->post_bit = (k + 4) * 8;
                st->post_end = r.nbits;
                break;
            }
            sc = 1;
            r.pos = (k + 4) * 8;
            if (code != 0xBB) { st->tail_bit = at; break; }
        } else if (at_data_end(&r, r.pos)) {
            st->tail_bit = st->tail_end = r.pos;
            break;
        }
        plane *p = add_plane(st);
        if (!p) { st->tail_bit = at; break; }
        p->sc = sc;
        p->sc_code = sc ? code : 0xBB;
        if (read_plane(&r, c, st, p, period ? &st->p[period_at] : NULL) < 0) { st->tail_bit = at; break; }
        if (p->intra) { period = p; period_at = st->n; }
        st->n++;
    }
    return 1;
}

/* ---------------------------------------------------------------- writing */
typedef struct {
    uint8_t *d;
    size_t cap;            /* bytes */
    int64_t pos;           /* bits written */
    int full;
    /* where fields and structures lie in the output, for in-place edits and truncation */
    int64_t *fbit; uint8_t *fw; size_t nf, capf;
    int64_t *cut; size_t ncut, capcut;
} writer;

static void wbit(writer *w, int b)
{
    if ((size_t)(w->pos >> 3) >= w->cap) { w->full = 1; return; }
    uint8_t m = (uint8_t)(0x80u >> (w->pos & 7));
    if (b) w->d[w->pos >> 3] |= m; else w->d[w->pos >> 3] &= (uint8_t)~m;
    w->pos++;
}

static void wbits(writer *w, uint32_t v, int n)
{
    for (int i = n - 1; i >= 0; i--) wbit(w, (int)((v >> i) & 1));
}

static void note_field(writer *w, int width)
{
    if (w->nf == w->capf) {
        size_t nc = w->capf ? w->capf * 2 : 256;
        int64_t *b = realloc(w->fbit, nc * sizeof *b);
        if (!b) return;
        w->fbit = b;
        uint8_t *x = realloc(w->fw, nc);
        if (!x) return;
        w->fw = x;
        w->capf = nc;
    }
    w->fbit[w->nf] = w->pos;
    w->fw[w->nf++] = (uint8_t)width;
}

static void field(writer *w, uint32_t v, int n)
{
    note_field(w, n);
    wbits(w, v, n);
}

static void note_cut(writer *w)
{
    if (w->ncut == w->capcut) {
        size_t nc = w->capcut ? w->capcut * 2 : 64;
        int64_t *b = realloc(w->cut, nc * sizeof *b);
        if (!b) return;
        w->cut = b;
        w->capcut = nc;
    }
    w->cut[w->ncut++] = w->pos;
}

static void start_code(writer *w, uint8_t code)
{
    wbit(w, 0); /* next_start_code(): a 0, then 1s up to the byte boundary */
    while (w->pos & 7) wbit(w, 1);
    note_cut(w);
    wbits(w, 0x000001u, 24);
    note_field(w, 8);
    wbits(w, code, 8);
}

typedef struct { writer *w; uint32_t low, high; int pending, zeros; } aenc;

static void aemit(aenc *e, int b)
{
    wbit(e->w, b);
    if (b) {
        e->zeros = 0;
    } else if (++e->zeros == STUFF_RUN) {
        wbit(e->w, 1);
        e->zeros = 0;
    }
}

static void afollow(aenc *e, int b)
{
    aemit(e, b);
    for (; e->pending > 0; e->pending--) aemit(e, 1 - b);
}

static void aencode(aenc *e, model *m, int32_t value)
{
    int s = value - m->lo;
    if (s < 0) s = 0;
    if (s >= m->n) s = m->n - 1;
    uint32_t len = e->high - e->low + 1, total = (uint32_t)cum(m, 0);
    uint32_t high = e->low - 1 + (uint32_t)((uint64_t)len * (uint32_t)cum(m, s) / total);
    uint32_t low = e->low + (uint32_t)((uint64_t)len * (uint32_t)cum(m, s + 1) / total);
    for (;;) {
        if (high < Q2) {
            afollow(e, 0);
        } else if (low >= Q2) {
            afollow(e, 1);
            low -= Q2; high -= Q2;
        } else if (low >= Q1 && high < Q3) {
            e->pending++;
            low -= Q1; high -= Q1;
        } else {
            break;
        }
        low <<= 1;
        high = (high << 1) | 1;
    }
    e->low = low;
    e->high = high;
    if (model_update(m, s)) e->w->full = 1; /* out of memory: the mutation is dropped */
}

static void aflush(aenc *e)
{
    e->pending++;
    afollow(e, e->low < Q1 ? 0 : 1);
}

static int32_t clampi(int32_t v, int32_t lo, int32_t hi) { return v < lo ? lo : v > hi ? hi : v; }

/* High-level symbols [from, to) of plane p (0-2 the viseme block, 3-6 the expression block) coded
 * and the block ended; c->hl follows the values they give (hl[3] is viseme_def: symbol k >= 3 is
 * hl[k + 1]). A predicted difference is kept so that the value stays in its range unless `exact`. */
static void write_high(aenc *e, codec *c, const plane *p, int t, int exact, int from, int to)
{
    int B = blend_max(c->q), qd = c->q ? c->q : 1;
    for (int k = from; k < to; k++) {
        int32_t *hl = &c->hl[k < 3 ? k : k + 1], unit = HL_MAX[k] < 0 ? qd : 1, lim = HL_MAX[k] < 0 ? B : HL_MAX[k];
        model *m = &c->hm[t][k];
        int32_t v = p->sym[k];
        if (t && !exact) v = clampi(v, -*hl / unit, lim - *hl / unit);
        aencode(e, m, v);
        v = clampi(v, m->lo, m->lo + m->n - 1);
        *hl = t ? *hl + v * unit : v * unit;
    }
    aflush(e);
    *e = (aenc){e->w, 0, TOP, 0, 0};
}

/* A DCT group's payload written as read_dct reads it (the zero run entering it counted back over
 * what is written; a run or level out of range written as it is: the decoder judges it). */
typedef struct { writer *w; int zrun; } pwriter;

static void pwbit(pwriter *p, int b)
{
    wbit(p->w, b);
    if (b) {
        p->zrun = 0;
    } else if (++p->zrun >= STUFF_RUN) {
        wbit(p->w, 1);
        p->zrun = 0;
    }
}

static void pwbits(pwriter *p, uint64_t v, int n)
{
    for (int i = n - 1; i >= 0; i--) pwbit(p, (int)((v >> i) & 1));
}

static void eg_write(pwriter *p, int32_t v, int k)
{
    uint64_t m = (v > 0 ? 2 * (uint64_t)v - 1 : 2 * (uint64_t)(-(int64_t)v)) + ((uint64_t)1 << k);
    int e = 0;
    while (m >> (e + 1)) e++;
    for (int z = e - k; z > 0; z--) pwbit(p, 0);
    pwbit(p, 1);
    pwbits(p, m - ((uint64_t)1 << e), e);
}

static void ac_write(pwriter *p, int run, int level)
{
    int a = level < 0 ? -level : level;
    for (size_t e = 0; e < sizeof AC_TABLE / sizeof *AC_TABLE; e++)
        if (AC_TABLE[e].run == run && AC_TABLE[e].level == a) {
            pwbits(p, AC_TABLE[e].code, AC_TABLE[e].len);
            pwbit(p, level < 0);
            return;
        }
    pwbits(p, AC_ESCAPE_CODE, AC_ESCAPE_LEN);
    pwbits(p, (uint32_t)run & 15, 4);
    pwbits(p, (uint32_t)a & AC_MAX_LEVEL, 14);
    pwbit(p, level < 0);
}

static void write_dct(writer *w, const codec *c, int intra, const dctdata *dd)
{
    pwriter p = {w, 0};
    while (p.zrun < STUFF_RUN && w->pos - 1 - p.zrun >= 0) {
        int64_t b = w->pos - 1 - p.zrun;
        if ((w->d[b >> 3] >> (7 - (b & 7))) & 1) break;
        p.zrun++;
    }
    pwbits(&p, dd->len1 & 15u, 4);
    for (int pass = 0; pass < 2; pass++) {
        if (!c->coded[pass]) continue;
        for (int j = 0; j <= (dd->len1 & 15); j++) {
            int first = intra && j == 0;
            if (!first) {
                pwbit(&p, dd->rep[pass][j]);
                if (dd->rep[pass][j]) continue;
            }
            for (int f = 0; f < 6 && HL_WIDTH[pass][first][f]; f++) {
                int width = HL_WIDTH[pass][first][f];
                pwbits(&p, dd->hv[pass][j][f] & ((1u << width) - 1), width);
            }
        }
    }
    for (int i = 2; i < NFAP; i++) {
        if (!c->coded[i]) continue;
        note_cut(w);
        eg_write(&p, dd->dc[i], intra ? 3 : 2);
        for (int n = 0; n < dd->nev[i]; n++) ac_write(&p, dd->run[i][n], dd->lev[i][n]);
        pwbit(&p, 0); /* end of block */
    }
    if (p.zrun >= 20) wbit(w, 1);
}

/* The stream written from its structure; `exact`: predicted high-level differences written as they
 * are (else kept so that the value they give stays in its range). */
static void write_stream(const stream *st, writer *w, int exact, codec *c)
{
    codec_clear(c);
    wbits(w, 0x000001BAu, 32);
    for (size_t k = 0; k < st->n && !w->full; k++) {
        const plane *p = &st->p[k];
        if (p->sc) start_code(w, p->sc_code);
        note_cut(w);
        int intra = p->intra || c->planes == 0; /* the first plane is intra (D2): a flip made it so */
        field(w, (uint32_t)intra, 1);
        field(w, p->om, 2);
        if (intra) {
            field(w, p->is_fr, 1);
            if (p->is_fr) { field(w, p->fr, 8); field(w, p->sec, 4); field(w, p->fo, 1); }
            field(w, p->is_tc, 1);
            if (p->is_tc) { field(w, p->h, 5); field(w, p->m, 6); field(w, 1, 1); field(w, p->s, 6); }
        }
        field(w, p->skip_flag, 1);
        if (p->skip_flag) {
            uint32_t left = p->skip;
            for (; left >= 15 && !w->full; left -= 15) field(w, 15, 4);
            field(w, left, 4);
        }
        if (intra) {
            field(w, p->q, 5);
            for (int g = 0; g < 10; g++) {
                field(w, 1, 1);
                field(w, p->mtype[g], 2);
                if (lists_bits(p->mtype[g]))
                    for (int j = 0; j < GROUP_SIZE[g]; j++) field(w, p->mbit[GROUP_FIRST[g] + j], 1);
            }
            field(w, p->gender, 1);
            field(w, p->coding, 1);
            if (!p->coding) {
                for (int l = 0; l < 4; l++) field(w, p->lflag[l], 1);
                for (int l = 0; l < 4; l++) {
                    if (!p->lflag[l]) continue;
                    for (int g = 1; g < 10; g++)
                        for (int j = 0; j < GROUP_SIZE[g]; j++) {
                            int i = GROUP_FIRST[g] + j;
                            if (j % 4 == 0) field(w, 1, 1);
                            if (coded_in(p, g, i)) field(w, p->lval[l][i], 5);
                        }
                }
            }
            if (codec_intra(c, p)) { w->full = 1; break; }
        }
        c->planes++;
        note_cut(w);
        if (c->coding) { /* a plane that became a DCT group without a payload gets an empty one */
            static const dctdata none;
            write_dct(w, c, intra, p->dct >= 0 ? &st->dp[p->dct] : &none);
            continue;
        }
        int t = intra ? 0 : 1;
        aenc e = {w, 0, TOP, 0, 0};
        if (c->coded[0]) {
            write_high(&e, c, p, t, exact, 0, 3);
            field(w, p->vdef, 1);
        }
        if (c->coded[1]) {
            write_high(&e, c, p, t, exact, 3, NHM);
            field(w, p->initf, 1);
            field(w, p->edef, 1);
        }
        note_cut(w);
        for (int i = 2; i < NFAP; i++)
            if (c->coded[i]) aencode(&e, &c->lm[t][i], p->sym[NHM + i - 2]);
        aflush(&e);
    }
    for (int64_t b = st->tail_bit; b < st->tail_end && !w->full; b++) /* the raw tail */
        wbit(w, (st->tail[b >> 3] >> (7 - (b & 7))) & 1);
    if (st->end_code && st->tail_bit == st->tail_end) {
        start_code(w, 0xB1);
        for (int64_t b = st->post_bit; b < st->post_end && !w->full; b++) /* what follows the end code */
            wbit(w, (st->tail[b >> 3] >> (7 - (b & 7))) & 1);
    }
    while (w->pos & 7) wbit(w, 0);
}

/* ---------------------------------------------------------------- mutations */
static int32_t pick_value(fba_rng *r, int32_t lo, int32_t hi, int32_t old)
{
    switch (below(r, 6)) {
    case 0: return lo;
    case 1: return hi;
    case 2: return old + 1;
    case 3: return old - 1;
    case 4: return 0;
    default: return lo + (int32_t)below(r, (uint32_t)(hi - lo + 1));
    }
}

/* The intra plane whose header plane k decodes under (the first plane is intra, D2). */
static size_t period_of(const stream *st, size_t k)
{
    while (k > 0 && !st->p[k].intra) k--;
    return k;
}

/* The group of low-level FAP i (0-based). */
static int group_of(int i)
{
    int g = 9;
    while (GROUP_FIRST[g] > i) g--;
    return g;
}

/* Coefficients FAP i's AC events take in a DCT group (each its run of zeros and itself); at most 15. */
static int ac_used(const dctdata *dd, int i)
{
    int used = 0;
    for (int e = 0; e < dd->nev[i]; e++) used += dd->run[i][e] + 1;
    return used;
}

/* Plane p's DCT payload, an empty one made for a plane that has none; NULL out of memory. */
static dctdata *dct_of(stream *st, plane *p)
{
    if (p->dct < 0 && (p->dct = add_dct(st)) < 0) return NULL;
    return &st->dp[p->dct];
}

/* The alphabet of the symbol `which` of plane k (0..2 viseme, 3..6 expression, 7+ low-level FAP
 * which-7+2), from the header in force there. */
static void alphabet(const stream *st, size_t k, int which, int32_t *lo, int32_t *hi)
{
    size_t pi = period_of(st, k);
    const plane *ip = &st->p[pi];
    int intra = st->p[k].intra, q = ip->q ? ip->q : 1, B = blend_max(ip->q);
    if (which < NHM) {
        int m = HL_MAX[which] < 0 ? B : HL_MAX[which];
        *lo = intra ? 0 : -m;
        *hi = m;
        return;
    }
    int i = which - NHM + 2;
    int32_t b[4];
    for (int l = 0; l < 4; l++) { /* the latest list that set it, else the default */
        b[l] = (l < 2 ? (IRANGE[i] + 59) / 60 : (PRANGE[i] + 59) / 60) * 60;
        for (size_t j = 0; j <= pi; j++)
            if (st->p[j].intra && st->p[j].lflag[l]) b[l] = st->p[j].lval[l][i] * 60;
    }
    *lo = -(intra ? b[1] : b[3]) / q;
    *hi = (intra ? b[0] : b[2]) / q;
}

/* A header field's new value: half the time any value of its width (fields are narrow: a 5-bit hour
 * is drawn uniformly), else an end or a neighbour of the old one. */
static uint32_t pick_field(fba_rng *r, uint32_t top, uint32_t old)
{
    switch (below(r, 8)) {
    case 0: return 0;
    case 1: return top;
    case 2: return (old + 1) & top;
    case 3: return (old - 1) & top;
    default: return fba_rand(r) & top;
    }
}

/* A FAP coded in plane k (10 draws; else any low-level FAP) */
static int coded_fap(const stream *st, size_t k, fba_rng *r)
{
    const plane *ip = &st->p[period_of(st, k)];
    int i = 2 + (int)below(r, NFAP - 2);
    for (int n = 0; n < 10 && !coded_in(ip, group_of(i), i); n++) i = 2 + (int)below(r, NFAP - 2);
    return i;
}

/* One thing of a DCT group's payload: an AC event's run (the largest that keeps the events inside
 * coefficients 1-15 lands the last on 15), its level, an event added or dropped, the DC value, the
 * segment length, a high-level field; rarely a run past coefficient 15. */
static void mutate_dct(stream *st, fba_rng *r, plane *p, size_t k)
{
    dctdata *dd = dct_of(st, p);
    if (!dd) return;
    int i = coded_fap(st, k, r), n = dd->nev[i], slack = 15 - ac_used(dd, i), e = n ? (int)below(r, (uint32_t)n) : 0;
    switch (below(r, 8)) {
    case 0:
    case 1:
        if (!n) break;
        if (below(r, 8) == 0) dd->run[i][e] = (uint8_t)below(r, 16);
        else dd->run[i][e] = (uint8_t)clampi(pick_value(r, 0, dd->run[i][e] + slack, dd->run[i][e]), 0, 15);
        break;
    case 2:
        if (n) dd->lev[i][e] = (int16_t)clampi(pick_value(r, -AC_MAX_LEVEL, AC_MAX_LEVEL, dd->lev[i][e]), -AC_MAX_LEVEL, AC_MAX_LEVEL);
        break;
    case 3: /* an event added */
        if (slack < 1) break;
        e = (int)below(r, (uint32_t)n + 1);
        memmove(&dd->run[i][e + 1], &dd->run[i][e], (size_t)(n - e));
        memmove(&dd->lev[i][e + 1], &dd->lev[i][e], (size_t)(n - e) * sizeof **dd->lev);
        dd->run[i][e] = (uint8_t)clampi(pick_value(r, 0, slack - 1, 0), 0, slack - 1);
        dd->lev[i][e] = (int16_t)((below(r, 2) ? 1 : -1) * (int32_t)(1 + below(r, 40)));
        dd->nev[i]++;
        break;
    case 4: /* an event dropped, or all */
        if (!n) break;
        if (below(r, 4) == 0) { dd->nev[i] = 0; break; }
        memmove(&dd->run[i][e], &dd->run[i][e + 1], (size_t)(n - e - 1));
        memmove(&dd->lev[i][e], &dd->lev[i][e + 1], (size_t)(n - e - 1) * sizeof **dd->lev);
        dd->nev[i]--;
        break;
    case 5: dd->dc[i] = pick_value(r, -(1 << 21), 1 << 21, dd->dc[i]); break;
    case 6: dd->len1 = (uint8_t)pick_field(r, 15, dd->len1); break;
    default: {
        int pass = (int)below(r, 2), j = (int)below(r, (uint32_t)(dd->len1 & 15) + 1), first = p->intra && j == 0;
        int f = (int)below(r, pass ? 6 : 4), width = HL_WIDTH[pass][first][f];
        if (!first && below(r, 3) == 0) dd->rep[pass][j] ^= 1;
        else dd->hv[pass][j][f] = (uint16_t)pick_field(r, (1u << width) - 1, dd->hv[pass][j][f]);
        break;
    }
    }
}

static void mutate_symbol(stream *st, fba_rng *r)
{
    size_t k = below(r, (uint32_t)st->n);
    plane *p = &st->p[k];
    if (st->p[period_of(st, k)].coding) {
        mutate_dct(st, r, p, k);
        return;
    }
    int which = (int)below(r, 10) < 3 ? (int)below(r, NHM) : NHM + (int)below(r, NFAP - 2);
    int32_t lo, hi, *v = &p->sym[which];
    alphabet(st, k, which, &lo, &hi);
    *v = clampi(pick_value(r, lo, hi, *v), lo, hi);
}

static void mutate_header(stream *st, fba_rng *r)
{
    /* the first plane a third of the time: where a decoder sets itself up (rate, period header, models) */
    plane *p = &st->p[below(r, 3) == 0 ? 0 : below(r, (uint32_t)st->n)];
    int i = 2 + (int)below(r, NFAP - 2);
    switch (below(r, 19)) {
    case 18: p->coding ^= 1; break; /* arithmetic <-> DCT segments (a DCT group without a payload gets an empty one) */
    case 16: p->is_fr = 1; p->fr = 0; p->sec = 0; break; /* the zero rate (a division by it, a loop stepping by it) */
    case 17: p->is_tc = 1; p->h = (uint8_t)(23 + below(r, 9)); p->m = (uint8_t)(59 + below(r, 5)); p->s = (uint8_t)(59 + below(r, 5)); break;
    case 0: p->is_fr = 1; p->fr = (uint8_t)pick_field(r, 255, p->fr); break;
    case 1: p->is_fr = 1; p->sec = (uint8_t)pick_field(r, 15, p->sec); p->fo = (uint8_t)below(r, 2); break;
    case 2: p->is_tc = 1; p->h = (uint8_t)pick_field(r, 31, p->h); break;
    case 3: p->is_tc = 1; p->m = (uint8_t)pick_field(r, 63, p->m); p->s = (uint8_t)pick_field(r, 63, p->s); break;
    case 4: {
        static const uint32_t SK[] = {0, 1, 14, 15, 16, 29, 30, 89, 90, 104, 1000, 65535};
        p->skip_flag = 1;
        p->skip = below(r, 2) ? SK[below(r, sizeof SK / sizeof *SK)] : below(r, 300);
        break;
    }
    case 5: p->skip_flag ^= 1; break;
    case 6: p->q = (uint8_t)pick_field(r, 31, p->q); break;
    case 7: { int g = (int)below(r, 10); p->mtype[g] = (uint8_t)below(r, 4); break; }
    case 8: { /* a FAP in or out of the mask (its group's mask then lists FAPs one by one) */
        int g = group_of(i);
        if (p->mtype[g] == 0 || p->mtype[g] == 3) p->mtype[g] = 1;
        p->mbit[i] ^= 1;
        break;
    }
    case 9: p->gender ^= 1; break;
    case 10: p->lflag[below(r, 4)] ^= 1; break;
    case 11: { int l = (int)below(r, 4); p->lflag[l] = 1; p->lval[l][i] = (uint8_t)pick_field(r, 31, p->lval[l][i]); break; }
    case 12: p->intra ^= 1; break;
    case 13: p->is_fr ^= 1; break;
    case 14: p->is_tc ^= 1; break;
    default: p->vdef ^= 1; p->initf = (uint8_t)below(r, 2); p->edef = (uint8_t)below(r, 2); break;
    }
}

/* Many fields of one plane at an end at once, structure-level interesting values: a bug behind
 * several conditions (a long block of extreme symbols and its stuffing, a list at its top at a coarse
 * quantiser, an AC event on the last coefficient) lies where single mutations seldom meet. */
static void mutate_extremes(stream *st, fba_rng *r)
{
    size_t k = below(r, (uint32_t)st->n);
    plane *p = &st->p[k];
    int top = (int)below(r, 2); /* all at the top, or all at the bottom; each part three times in four */
    if (k > 0 && below(r, 2)) p->intra = 1; /* half the time a new period's header (a predicted plane keeps its period's) */
    if (p->intra) {
        if (below(r, 4)) p->q = top ? 31 : 1;
        if (below(r, 4))
            for (int g = 0; g < 10; g++) p->mtype[g] = 3; /* every FAP coded */
        if (below(r, 4))
            for (int l = 0; l < 4; l++) { /* every min/max list sent, each bound at 31 or 0 (x 60) */
                p->lflag[l] = 1;
                for (int i = 2; i < NFAP; i++) p->lval[l][i] = top ? 31 : 0;
            }
    }
    if (st->p[period_of(st, k)].coding) { /* every FAP's last AC event on coefficient 15 */
        dctdata *dd = dct_of(st, p);
        if (!dd) return;
        for (int i = 2; i < NFAP; i++) {
            int n = dd->nev[i];
            if (n) {
                dd->run[i][n - 1] = (uint8_t)clampi(dd->run[i][n - 1] + 15 - ac_used(dd, i), 0, 15);
            } else {
                dd->nev[i] = 1;
                dd->run[i][0] = 14;
            }
            if (top) dd->lev[i][dd->nev[i] - 1] = AC_MAX_LEVEL;
            else if (!dd->lev[i][dd->nev[i] - 1]) dd->lev[i][dd->nev[i] - 1] = 1;
        }
        return;
    }
    for (int which = 0; which < NSYM; which++) { /* every symbol at one end of its alphabet */
        int32_t lo, hi;
        alphabet(st, k, which, &lo, &hi);
        p->sym[which] = top ? hi : lo;
    }
}

static void mutate_planes(stream *st, fba_rng *r)
{
    size_t a = below(r, (uint32_t)st->n), b = below(r, (uint32_t)st->n);
    switch (below(r, 5)) {
    case 0: /* drop */
        if (st->n > 1) { memmove(&st->p[a], &st->p[a + 1], (st->n - a - 1) * sizeof *st->p); st->n--; }
        break;
    case 1: /* duplicate */
        if (st->n < st->cap || add_plane(st)) {
            memmove(&st->p[a + 1], &st->p[a], (st->n - a) * sizeof *st->p);
            st->n++;
        }
        break;
    case 2: { /* swap */
        plane t = st->p[a];
        st->p[a] = st->p[b];
        st->p[b] = t;
        break;
    }
    case 3: st->p[a].sc ^= 1; st->p[a].sc_code = 0xBB; break;
    default: st->end_code ^= 1; break;
    }
}

/* ---------------------------------------------------------------- working memory */
/* What a call needs is kept for the next call of its thread: two streams' tables, the codec (a
 * parse's, then a write's), the writer's notes and the byte buffers. A fuzzer calls the mutator
 * thousands of times a second, and in a sanitizer build (a libFuzzer target: the mutator's
 * allocations go through ASan's allocator, whose quarantine holds freed memory back) fresh tables on
 * every call touched fresh pages: 16 % of a libFuzzer run went to page faults. */
typedef struct {
    stream s[2];
    codec c;
    uint8_t *src, *out;
    size_t capsrc, capout;
    int64_t *fbit, *cut;
    uint8_t *fw;
    size_t capf, capcut;
} scratch;

static _Thread_local scratch *tls_scratch;

static scratch *scratch_get(void)
{
    if (!tls_scratch) tls_scratch = calloc(1, sizeof *tls_scratch);
    return tls_scratch;
}

/* A byte buffer of at least n bytes (1 at least), kept in *buf; NULL when it cannot grow. */
static uint8_t *bytes_of(uint8_t **buf, size_t *cap, size_t n)
{
    if (n == 0) n = 1;
    if (*cap < n) {
        uint8_t *b = realloc(*buf, n);
        if (!b) return NULL;
        *buf = b;
        *cap = n;
    }
    return *buf;
}

static size_t emit(scratch *sc, const stream *st, uint8_t *out, size_t max, fba_rng *r, int exact, int raw_op)
{
    writer w = {out, max, 0, 0, sc->fbit, sc->fw, 0, sc->capf, sc->cut, 0, sc->capcut};
    write_stream(st, &w, exact, &sc->c);
    sc->fbit = w.fbit; /* the notes' tables, grown or not, for the next call */
    sc->fw = w.fw;
    sc->capf = w.capf;
    sc->cut = w.cut;
    sc->capcut = w.capcut;
    size_t n = (size_t)((w.pos + 7) >> 3);
    if (raw_op == 1 && w.nf) { /* a field written in place: markers, reserved values, out of range */
        size_t f = below(r, (uint32_t)w.nf);
        int width = w.fw[f];
        uint32_t top = width >= 32 ? 0xFFFFFFFFu : (1u << width) - 1, v = pick_field(r, top, 0);
        int64_t at = w.fbit[f];
        for (int i = width - 1; i >= 0 && (size_t)(at >> 3) < n; i--, at++) {
            uint8_t m = (uint8_t)(0x80u >> (at & 7));
            if ((v >> i) & 1) out[at >> 3] |= m; else out[at >> 3] &= (uint8_t)~m;
        }
    } else if (raw_op == 2 && w.ncut) { /* truncation at a structure boundary */
        int64_t cut = w.cut[below(r, (uint32_t)w.ncut)];
        n = (size_t)((cut + 7) >> 3);
    }
    if (w.full) return 0;
    return n;
}

/* One structure-aware mutation of data[0, size) in place (at most max_size bytes); the new size. */
size_t fba_mutate(uint8_t *data, size_t size, size_t max_size, unsigned int seed)
{
    fba_rng r = {0x9E3779B97F4A7C15ULL ^ seed};
    scratch *sc = scratch_get();
    stream *st = sc ? &sc->s[0] : NULL;
    if (!st || !parse(data, size, st, &sc->c) || st->n == 0) { /* not a face object stream we can read: one bit */
        if (size) data[below(&r, (uint32_t)size)] ^= (uint8_t)(1u << below(&r, 8));
        return size;
    }
    /* the raw tail points into data, which the output overwrites: keep a copy */
    uint8_t *src = bytes_of(&sc->src, &sc->capsrc, size), *out = bytes_of(&sc->out, &sc->capout, max_size);
    if (!src || !out) return size;
    memcpy(src, data, size);
    st->tail = src;
    uint32_t op = below(&r, 21);
    int exact = 0, raw_op = 0;
    if (op < 8) {
        for (uint32_t k = 1 + (below(&r, 4) == 0 ? below(&r, 4) : 0); k > 0; k--) mutate_symbol(st, &r);
        exact = below(&r, 4) == 0;
    } else if (op < 14) {
        mutate_header(st, &r);
    } else if (op < 16) {
        mutate_planes(st, &r);
    } else if (op < 18) {
        raw_op = 1;
    } else if (op < 19) {
        raw_op = 2;
    } else if (op < 20) {
        mutate_extremes(st, &r);
    } else {
        plane *p = &st->p[below(&r, (uint32_t)st->n)]; /* another start code where a plane's is */
        p->sc = 1;
        p->sc_code = (uint8_t)(below(&r, 2) ? 0xB0 + below(&r, 16) : fba_rand(&r));
    }
    size_t n = emit(sc, st, out, max_size, &r, exact, raw_op);
    if (n) memcpy(data, out, n); else n = size;
    return n;
}

/* The stream parsed and written again without a mutation (what every mutation starts from): for a
 * stream the reference encoder wrote, the same bytes. 0 when it is not a face object stream. */
size_t fba_rewrite(const uint8_t *data, size_t size, uint8_t *out, size_t max_size)
{
    scratch *sc = scratch_get();
    fba_rng r = {1};
    size_t n = 0;
    if (sc && parse(data, size, &sc->s[0], &sc->c) && sc->s[0].n) n = emit(sc, &sc->s[0], out, max_size, &r, 1, 0);
    return n;
}

/* The stream with one symbol set: of plane `k` (counted from 0), symbol `which` (0-2 the viseme block,
 * 3-6 the expression block, 7 + i - 2 the low-level FAP i, 0-based) to `value` (kept in its alphabet),
 * written again. The edit a fuzzer makes, by hand: for tools and tests. 0 on no such plane. */
size_t fba_edit_symbol(const uint8_t *data, size_t size, uint8_t *out, size_t max_size, size_t k, int which,
                       int32_t value)
{
    scratch *sc = scratch_get();
    stream *st = sc ? &sc->s[0] : NULL;
    fba_rng r = {1};
    size_t n = 0;
    if (st && parse(data, size, st, &sc->c) && k < st->n && which >= 0 && which < NSYM) {
        plane *p = &st->p[k];
        int32_t lo, hi;
        alphabet(st, k, which, &lo, &hi);
        p->sym[which] = clampi(value, lo, hi);
        n = emit(sc, st, out, max_size, &r, 1, 0);
    }
    return n;
}

/* The planes of `a` up to one of them, then the planes of `b` from one of them, written again. */
size_t fba_cross(const uint8_t *a, size_t na, const uint8_t *b, size_t nb, uint8_t *out, size_t max, unsigned int seed)
{
    fba_rng r = {0xD1B54A32D192ED03ULL ^ seed};
    scratch *sc = scratch_get();
    stream *sa = sc ? &sc->s[0] : NULL, *sb = sc ? &sc->s[1] : NULL;
    size_t n = 0;
    if (sc && parse(a, na, sa, &sc->c) && parse(b, nb, sb, &sc->c) && sa->n && sb->n) {
        size_t cut = 1 + below(&r, (uint32_t)sa->n), from = below(&r, (uint32_t)sb->n), more = sb->n - from;
        while (sa->n > cut) sa->n--;
        for (size_t k = 0; k < more; k++) {
            plane *p = add_plane(sa);
            if (!p) break;
            *p = sb->p[from + k];
            if (p->dct >= 0) { /* its payload moves into a's pool */
                int32_t at = add_dct(sa);
                if (at >= 0) sa->dp[at] = sb->dp[p->dct];
                p->dct = at;
            }
            sa->n++;
        }
        sa->tail = sb->tail;
        sa->tail_bit = sb->tail_bit;
        sa->tail_end = sb->tail_end;
        sa->end_code = sb->end_code;
        sa->post_bit = sb->post_bit;
        sa->post_end = sb->post_end;
        n = emit(sc, sa, out, max, &r, 0, 0);
    }
    if (!n) {
        n = na < max ? na : max;
        memcpy(out, a, n);
    }
    return n;
}

#ifdef FBA_LIBFUZZER
size_t LLVMFuzzerMutate(uint8_t *data, size_t size, size_t max_size);

size_t LLVMFuzzerCustomMutator(uint8_t *data, size_t size, size_t max_size, unsigned int seed)
{
    if (seed % 8 == 0) return LLVMFuzzerMutate(data, size, max_size); /* keep a share of byte-level havoc */
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
    /* AFL++ mutates each queue entry afresh (libFuzzer stacks up to five mutations on one input), and a
     * bug behind two steps (a plane made predicted, then its symbol at an end) needs both at once: 1, 2
     * or 4 mutations stacked, after a crossover with another queue entry one time in eight */
    unsigned int seed = fba_rand(&m->r), k = 1u << (seed >> 8) % 3;
    size_t n;
    if (add_buf && add_buf_size && seed % 8 == 0) {
        n = fba_cross(buf, buf_size, add_buf, add_buf_size, m->buf, max_size, seed);
        k--;
    } else {
        n = buf_size < max_size ? buf_size : max_size;
        memcpy(m->buf, buf, n);
    }
    for (; k > 0; k--) n = fba_mutate(m->buf, n, max_size, fba_rand(&m->r));
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
