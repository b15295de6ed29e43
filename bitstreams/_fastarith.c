/*
 * Native inner loop of fbaconf's adaptive arithmetic coder (optional C extension).
 *
 * Written for fbaconf from the spec notes (../shared/spec/fap-bitstream.md section 3 and
 * decision D7) and the pure-Python reference in arith.py / decoder.py / encoder.py, which
 * stay the reference and the fallback: this module must give bit-identical results and
 * report every error at the same place (tests/unit/test_native.py checks it differentially).
 *
 * Coder: 16-bit registers (top 65535, q1 16384, q2 32768, q3 49152); cumulative
 * frequency tables c[0..n] in descending suffix-sum form (c[0] = total, c[n] = 0),
 * symbol s occupying [c[s+1], c[s]); adaptive models add 1 to c[0..s] after each symbol,
 * halving every frequency (rounding up) first when the total has reached 16383.
 * Start-code emulation prevention: a '1' after every 22nd consecutive '0'.
 *
 * A block is described by a "spec": an int32 array of k rows (n, off, lo, step, idx):
 *   n     alphabet size
 *   off   offset of the model's c table (n + 1 int32) in the pool, or -1 for a
 *         non-adaptive uniform model (c[k] = n - k, no table)
 *   lo    value of symbol 0 (the decoded value is symbol + lo)
 *   step  quantiser step (decode modes 1 and 2)
 *   idx   index into the list ``cur`` (decode modes 1 and 2)
 *
 * decode_block(data, nbits, pos, spec, pool, mode, cur) decodes one block starting at
 * bit ``pos``:
 *   mode 0  only the values;  mode 1  cur[idx] = value * step (intra);
 *   mode 2  v = cur[idx] + value * step, which must lie in +-(2**31 - 1), cur[idx] = v.
 * It returns
 *   (0, end, values)       the block ends at bit ``end`` (D7); values is a list
 *   (1, pos, i)            decoder state out of range at symbol i, reader at bit pos
 *   (2, at, None)          stuffing bit at ``at`` is not '1' (inside the block)
 *   (3, nbits, None)       the data ends inside the block
 *   (4, i, v)              mode 2: the value v of row i overflows 32 bits
 * mirroring ArithDecoder.decode / ArithDecoder.finish and the decoder's overflow check,
 * in the same order.
 *
 * encode_block(spec, pool, values) codes one block (values are symbol + lo) and flushes;
 * it returns (0, bytes, nbits) or (1, i, s) when row i's symbol index s is outside its
 * alphabet.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <stdint.h>
#include <string.h>

#define TOP 65535
#define Q1 16384
#define Q2 32768
#define Q3 49152
#define MAX_FREQUENCY 16383
#define ZERO_RUN_LIMIT 22
#define LOOKAHEAD 14
#define SPEC_COLS 5
#define INT32_LIMIT 2147483647LL

/* floor division (Python semantics), b > 0 */
static inline long long floordiv_ll(long long a, long long b) {
    long long q = a / b;
    if ((a % b) != 0 && (a < 0)) q -= 1;
    return q;
}

/* ------------------------------------------------------------------ models */

static inline long long model_total(const int32_t *c, long long n) {
    return c ? (long long)c[0] : n;
}

/* the symbol s with c[s+1] <= target < c[s] (0 <= target < total) */
static inline long long model_find(const int32_t *c, long long n, long long target) {
    if (!c) {
        long long k = n - target;
        return (k > 1 ? k : 1) - 1;
    }
    /* first k >= 1 with c[k] <= target; c is non-increasing, c[n] = 0 */
    long long lo = 1, hi = n;
    while (lo < hi) {
        long long mid = (lo + hi) >> 1;
        if (c[mid] <= target) hi = mid;
        else lo = mid + 1;
    }
    return lo - 1;
}

static inline void model_bounds(const int32_t *c, long long n, long long s, long long *hi_c, long long *lo_c) {
    if (!c) {
        *hi_c = n - s;
        *lo_c = n - s - 1;
    } else {
        *hi_c = c[s];
        *lo_c = c[s + 1];
    }
}

static inline void model_update(int32_t *c, long long n, long long s) {
    if (!c) return;
    if (c[0] == MAX_FREQUENCY) {
        int32_t old_next = c[n];
        int32_t acc = 0;
        for (long long k = n - 1; k >= 0; k--) {
            int32_t old = c[k];
            acc += (old - old_next + 1) >> 1;
            c[k] = acc;
            old_next = old;
        }
        c[n] = 0;
    }
    for (long long k = 0; k <= s; k++) c[k] += 1;
}

/* ------------------------------------------------------------------ buffers */

typedef struct {
    Py_buffer spec;
    Py_buffer pool;
    int have_spec, have_pool;
    const int32_t *rows;
    Py_ssize_t k;
    int32_t *pool_data;
    Py_ssize_t pool_len;
} Tables;

static void tables_release(Tables *t) {
    if (t->have_spec) PyBuffer_Release(&t->spec);
    if (t->have_pool) PyBuffer_Release(&t->pool);
    t->have_spec = t->have_pool = 0;
}

static int tables_get(Tables *t, PyObject *spec, PyObject *pool) {
    memset(t, 0, sizeof(*t));
    if (PyObject_GetBuffer(spec, &t->spec, PyBUF_C_CONTIGUOUS) < 0) return -1;
    t->have_spec = 1;
    if (t->spec.len % (Py_ssize_t)(SPEC_COLS * sizeof(int32_t)) != 0) {
        PyErr_SetString(PyExc_ValueError, "spec must be int32 rows of 5 columns");
        tables_release(t);
        return -1;
    }
    t->rows = (const int32_t *)t->spec.buf;
    t->k = t->spec.len / (Py_ssize_t)(SPEC_COLS * sizeof(int32_t));
    if (pool != Py_None) {
        if (PyObject_GetBuffer(pool, &t->pool, PyBUF_C_CONTIGUOUS | PyBUF_WRITABLE) < 0) {
            tables_release(t);
            return -1;
        }
        t->have_pool = 1;
        t->pool_data = (int32_t *)t->pool.buf;
        t->pool_len = t->pool.len / (Py_ssize_t)sizeof(int32_t);
    }
    /* validate every row before touching anything */
    for (Py_ssize_t i = 0; i < t->k; i++) {
        const int32_t *row = t->rows + i * SPEC_COLS;
        long long n = row[0], off = row[1];
        if (n < 1 || n > MAX_FREQUENCY) {
            PyErr_Format(PyExc_ValueError, "spec row %zd: alphabet size %lld outside 1..%d", i, n, MAX_FREQUENCY);
            tables_release(t);
            return -1;
        }
        if (off >= 0 && (t->pool_data == NULL || off + n + 1 > t->pool_len)) {
            PyErr_Format(PyExc_ValueError, "spec row %zd: model table outside the pool", i);
            tables_release(t);
            return -1;
        }
    }
    return 0;
}

static inline int32_t *row_table(const Tables *t, const int32_t *row) {
    return row[1] >= 0 ? t->pool_data + row[1] : NULL;
}

/* ------------------------------------------------------------------ decoder */

typedef struct {
    const unsigned char *data;
    long long nbits;
    long long pos;
    long long count;       /* arithmetic input bits read (stuffing excluded) */
    int zeros;
    long long nstuff;      /* stuffing bits consumed */
    long long last_stuff;  /* arith count at the last stuffing bit, -1 if none */
    long long bad_count;   /* arith count at the first '0' stuffing bit, -1 if none */
    long long bad_at;      /* its stream offset */
} Reader;

static inline int stream_bit(const Reader *r, long long p) {
    return p < r->nbits ? (r->data[p >> 3] >> (7 - (p & 7))) & 1 : 0;
}

static inline int read_bit(Reader *r) {
    int b = stream_bit(r, r->pos);
    r->pos += 1;
    r->count += 1;
    if (b) {
        r->zeros = 0;
    } else if (++r->zeros == ZERO_RUN_LIMIT) {
        long long at = r->pos;
        if (stream_bit(r, at) != 1 && r->bad_count < 0) {
            r->bad_count = r->count;
            r->bad_at = at;
        }
        r->pos = at + 1;
        r->nstuff += 1;
        r->last_stuff = r->count;
        r->zeros = 0;
    }
    return b;
}

static PyObject *status3(long long st, PyObject *a, PyObject *b) {
    /* steals a and b */
    if (!a || !b) {
        Py_XDECREF(a);
        Py_XDECREF(b);
        return NULL;
    }
    PyObject *t = PyTuple_New(3);
    if (!t) {
        Py_DECREF(a);
        Py_DECREF(b);
        return NULL;
    }
    PyTuple_SET_ITEM(t, 0, PyLong_FromLongLong(st));
    if (!PyTuple_GET_ITEM(t, 0)) {
        Py_DECREF(t);
        Py_DECREF(a);
        Py_DECREF(b);
        return NULL;
    }
    PyTuple_SET_ITEM(t, 1, a);
    PyTuple_SET_ITEM(t, 2, b);
    return t;
}

static PyObject *fa_decode_block(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    (void)self;
    if (nargs != 7) {
        PyErr_SetString(PyExc_TypeError, "decode_block(data, nbits, pos, spec, pool, mode, cur)");
        return NULL;
    }
    Py_buffer dbuf;
    if (PyObject_GetBuffer(args[0], &dbuf, PyBUF_SIMPLE) < 0) return NULL;
    long long nbits = PyLong_AsLongLong(args[1]);
    long long start = PyLong_AsLongLong(args[2]);
    long mode = PyLong_AsLong(args[5]);
    PyObject *cur = args[6];
    if (PyErr_Occurred()) {
        PyBuffer_Release(&dbuf);
        return NULL;
    }
    if (nbits < 0 || nbits > (long long)dbuf.len * 8 || start < 0 || mode < 0 || mode > 2) {
        PyBuffer_Release(&dbuf);
        PyErr_SetString(PyExc_ValueError, "bad nbits, pos or mode");
        return NULL;
    }
    Tables t;
    if (tables_get(&t, args[3], args[4]) < 0) {
        PyBuffer_Release(&dbuf);
        return NULL;
    }
    if (mode != 0) {
        if (!PyList_Check(cur)) {
            PyErr_SetString(PyExc_TypeError, "cur must be a list in modes 1 and 2");
            goto fail;
        }
        for (Py_ssize_t i = 0; i < t.k; i++) {
            int32_t idx = t.rows[i * SPEC_COLS + 4];
            if (idx < 0 || idx >= PyList_GET_SIZE(cur)) {
                PyErr_SetString(PyExc_IndexError, "spec index outside cur");
                goto fail;
            }
        }
    }
    PyObject *values = PyList_New(t.k);
    if (!values) goto fail;

    Reader r;
    r.data = (const unsigned char *)dbuf.buf;
    r.nbits = nbits;
    r.pos = start;
    r.count = 0;
    r.zeros = 0;
    r.nstuff = 0;
    r.last_stuff = -1;
    r.bad_count = -1;
    r.bad_at = -1;
    long long low = 0, high = TOP, value = 0;
    for (int i = 0; i < 16; i++) value = (value << 1) | read_bit(&r);

    for (Py_ssize_t i = 0; i < t.k; i++) {
        const int32_t *row = t.rows + i * SPEC_COLS;
        long long n = row[0];
        int32_t *c = row_table(&t, row);
        long long length = high - low + 1;
        long long total = model_total(c, n);
        long long target = floordiv_ll((value - low + 1) * total - 1, length);
        if (!(0 <= target && target < total)) {
            Py_DECREF(values);
            tables_release(&t);
            PyBuffer_Release(&dbuf);
            return status3(1, PyLong_FromLongLong(r.pos), PyLong_FromSsize_t(i));
        }
        long long s = model_find(c, n, target);
        long long hi_c, lo_c;
        model_bounds(c, n, s, &hi_c, &lo_c);
        high = low - 1 + floordiv_ll(length * hi_c, total);
        low = low + floordiv_ll(length * lo_c, total);
        for (;;) {
            if (high < Q2) {
                /* nothing */
            } else if (low >= Q2) {
                value -= Q2;
                low -= Q2;
                high -= Q2;
            } else if (low >= Q1 && high < Q3) {
                value -= Q1;
                low -= Q1;
                high -= Q1;
            } else {
                break;
            }
            low <<= 1;
            high = (high << 1) | 1;
            value = (value << 1) | read_bit(&r);
        }
        model_update(c, n, s);
        long long sym = s + row[2];
        if (mode == 1) {
            PyObject *v = PyLong_FromLongLong(sym * (long long)row[3]);
            if (!v) {
                Py_DECREF(values);
                goto fail;
            }
            PyList_SetItem(cur, row[4], v); /* steals v */
        } else if (mode == 2) {
            long long prev = PyLong_AsLongLong(PyList_GET_ITEM(cur, row[4]));
            if (prev == -1 && PyErr_Occurred()) {
                Py_DECREF(values);
                goto fail;
            }
            long long v = prev + sym * (long long)row[3];
            if (!(-INT32_LIMIT <= v && v <= INT32_LIMIT)) {
                Py_DECREF(values);
                tables_release(&t);
                PyBuffer_Release(&dbuf);
                return status3(4, PyLong_FromSsize_t(i), PyLong_FromLongLong(v));
            }
            PyObject *pv = PyLong_FromLongLong(v);
            if (!pv) {
                Py_DECREF(values);
                goto fail;
            }
            PyList_SetItem(cur, row[4], pv);
        }
        PyObject *sv = PyLong_FromLongLong(sym);
        if (!sv) {
            Py_DECREF(values);
            goto fail;
        }
        PyList_SET_ITEM(values, i, sv);
    }
    tables_release(&t);
    PyBuffer_Release(&dbuf);

    /* finish (D7): the block is LOOKAHEAD arithmetic bits shorter than what was read */
    long long used = r.count - LOOKAHEAD;
    if (r.bad_count >= 0 && r.bad_count <= used) {
        Py_DECREF(values);
        if (r.bad_at >= nbits) return status3(3, PyLong_FromLongLong(nbits), Py_NewRef(Py_None));
        return status3(2, PyLong_FromLongLong(r.bad_at), Py_NewRef(Py_None));
    }
    /* stuffing bits are >= 22 arithmetic bits apart, so at most the last one lies in the look-ahead */
    long long stuffed = r.nstuff - ((r.last_stuff > used) ? 1 : 0);
    long long end = start + used + stuffed;
    if (end > nbits) {
        Py_DECREF(values);
        return status3(3, PyLong_FromLongLong(nbits), Py_NewRef(Py_None));
    }
    return status3(0, PyLong_FromLongLong(end), values);

fail:
    tables_release(&t);
    PyBuffer_Release(&dbuf);
    return NULL;
}

/* ------------------------------------------------------------------ encoder */

typedef struct {
    unsigned char *buf;
    Py_ssize_t cap;
    long long nbits;
    int zeros;
} Writer;

static int put_bit(Writer *w, int b) {
    Py_ssize_t byte = (Py_ssize_t)(w->nbits >> 3);
    if (byte >= w->cap) {
        Py_ssize_t ncap = w->cap * 2;
        unsigned char *nb = PyMem_Realloc(w->buf, (size_t)ncap);
        if (!nb) {
            PyErr_NoMemory();
            return -1;
        }
        memset(nb + w->cap, 0, (size_t)(ncap - w->cap));
        w->buf = nb;
        w->cap = ncap;
    }
    if (b) w->buf[byte] |= (unsigned char)(0x80 >> (w->nbits & 7));
    w->nbits += 1;
    return 0;
}

static inline int emit(Writer *w, int b) {
    if (put_bit(w, b) < 0) return -1;
    if (b) {
        w->zeros = 0;
    } else if (++w->zeros == ZERO_RUN_LIMIT) {
        if (put_bit(w, 1) < 0) return -1;
        w->zeros = 0;
    }
    return 0;
}

static inline int bit_plus_follow(Writer *w, int b, long long *pending) {
    if (emit(w, b) < 0) return -1;
    while (*pending > 0) {
        if (emit(w, !b) < 0) return -1;
        *pending -= 1;
    }
    return 0;
}

static PyObject *fa_encode_block(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    (void)self;
    if (nargs != 3) {
        PyErr_SetString(PyExc_TypeError, "encode_block(spec, pool, values)");
        return NULL;
    }
    Tables t;
    if (tables_get(&t, args[0], args[1]) < 0) return NULL;
    Py_buffer vbuf;
    if (PyObject_GetBuffer(args[2], &vbuf, PyBUF_C_CONTIGUOUS) < 0) {
        tables_release(&t);
        return NULL;
    }
    if (vbuf.len != t.k * (Py_ssize_t)sizeof(int32_t)) {
        PyErr_SetString(PyExc_ValueError, "values must be int32, one per spec row");
        goto fail_v;
    }
    const int32_t *vals = (const int32_t *)vbuf.buf;
    Writer w;
    w.cap = 64 + t.k * 4;
    w.buf = PyMem_Calloc((size_t)w.cap, 1);
    w.nbits = 0;
    w.zeros = 0;
    if (!w.buf) {
        PyErr_NoMemory();
        goto fail_v;
    }
    long long low = 0, high = TOP, pending = 0;
    /* a symbol outside its alphabet stops the block (the reference raises ValueError there) */
    for (Py_ssize_t i = 0; i < t.k; i++) {
        const int32_t *row = t.rows + i * SPEC_COLS;
        long long n = row[0];
        long long s = (long long)vals[i] - row[2];
        if (!(0 <= s && s < n)) {
            PyMem_Free(w.buf);
            PyBuffer_Release(&vbuf);
            tables_release(&t);
            return status3(1, PyLong_FromSsize_t(i), PyLong_FromLongLong(s));
        }
        int32_t *c = row_table(&t, row);
        long long hi_c, lo_c;
        model_bounds(c, n, s, &hi_c, &lo_c);
        long long total = model_total(c, n);
        long long length = high - low + 1;
        high = low - 1 + floordiv_ll(length * hi_c, total);
        low = low + floordiv_ll(length * lo_c, total);
        for (;;) {
            if (high < Q2) {
                if (bit_plus_follow(&w, 0, &pending) < 0) goto fail_w;
            } else if (low >= Q2) {
                if (bit_plus_follow(&w, 1, &pending) < 0) goto fail_w;
                low -= Q2;
                high -= Q2;
            } else if (low >= Q1 && high < Q3) {
                pending += 1;
                low -= Q1;
                high -= Q1;
            } else {
                break;
            }
            low <<= 1;
            high = (high << 1) | 1;
        }
        model_update(c, n, s);
    }
    pending += 1;
    if (bit_plus_follow(&w, low < Q1 ? 0 : 1, &pending) < 0) goto fail_w;
    PyBuffer_Release(&vbuf);
    tables_release(&t);
    PyObject *bytes = PyBytes_FromStringAndSize((const char *)w.buf, (Py_ssize_t)((w.nbits + 7) >> 3));
    PyMem_Free(w.buf);
    if (!bytes) return NULL;
    return status3(0, bytes, PyLong_FromLongLong(w.nbits));

fail_w:
    PyMem_Free(w.buf);
fail_v:
    PyBuffer_Release(&vbuf);
    tables_release(&t);
    return NULL;
}

/* ------------------------------------------------------------------ module */

static PyMethodDef methods[] = {
    {"decode_block", (PyCFunction)(void (*)(void))fa_decode_block, METH_FASTCALL,
     "decode_block(data, nbits, pos, spec, pool, mode, cur) -> (status, a, b); see the module source"},
    {"encode_block", (PyCFunction)(void (*)(void))fa_encode_block, METH_FASTCALL,
     "encode_block(spec, pool, values) -> (status, a, b); see the module source"},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef moddef = {
    PyModuleDef_HEAD_INIT, "_fastarith",
    "Native inner loop of fbaconf's adaptive arithmetic coder (optional; arith.py is the reference).",
    -1, methods, NULL, NULL, NULL, NULL,
};

PyMODINIT_FUNC PyInit__fastarith(void) {
    PyObject *m = PyModule_Create(&moddef);
    if (!m) return NULL;
    if (PyModule_AddIntConstant(m, "SPEC_COLS", SPEC_COLS) < 0 || PyModule_AddIntConstant(m, "ABI", 1) < 0) {
        Py_DECREF(m);
        return NULL;
    }
    return m;
}
