/*
 * Native scan conversion and depth test of fbaconf's reference rasteriser (optional C extension).
 *
 * rendering/raster.py stays the reference and the fallback: this module computes the same
 * visibility — for every sample of the grid, the triangle whose fragment is nearest (largest
 * interpolated 1/d), exact ties to the lowest triangle index — with the same integer edge
 * functions and the same floating-point operations in the same order (built with
 * -ffp-contract=off: no fused multiply-add), so the winners are identical; the barycentrics of
 * the winners are then computed by raster.py in numpy as before. tests/unit/test_rendering.py checks
 * the two paths against each other; `fbaconf golden verify` reproduces every golden image.
 *
 * winners(width, height, far, any_beyond, tri_i64, tri_f64, beyond_u8, zbuf_f64, tbuf_i64)
 *   tri_i64  int64[m, 20]: X0, Y0, px0, py0, si0, sj0, bw, bh, then per edge q = 0..2:
 *            thr_q, w_org_q, sx_q, sy_q (raster.rasterize's names)
 *   tri_f64  float64[m, 4]: iz0, A, B, A * SUB
 *   beyond   uint8[m]: the triangle reaches beyond the far plane
 *   zbuf     float64[width * height], filled with 0.0 by the caller (1/d of the winner)
 *   tbuf     int64[width * height], filled with -1 by the caller (the winner's row in tri_*)
 *
 * resolve(width, tbuf_i64, tri_i64, tri_f64, wp_i64, wt_i64, b0, b1, b2) -> n
 *   the winners in sample order and their perspective-correct barycentrics, as raster.py
 *   computes them: exact int64 edge functions w1 (edge v2->v0), w2 (edge v0->v1), w0 = area - w1
 *   - w2 at the sample centre, q_i = (w_i / area) * iz_i, b_i = q_i / (q0 + q1 + q2).
 *   tri_i64  int64[m, 7]: X0, Y0, X1, Y1, X2, Y2, area
 *   tri_f64  float64[m, 4]: area (as a double), iz0, iz1, iz2
 *   wp, wt, b0, b1, b2: outputs of width * height items; the first n are filled
 *
 * box_downsample(planes_f64, channels, height, width, n, out_f64): the n x n box filter of
 *   raster.box_downsample_planes, in its order: each sample row's n samples added left to right,
 *   then the n row sums top to bottom, then divided by n * n.
 *
 * interp_scatter(f_f64, i0, i1, i2, b0, b1, b2, pix, img_f64): Gouraud interpolation of the lit
 *   colours, as render.py computes it: img[c][pix[j]] = b0[j] * f[c][i0[j]] + b1[j] * f[c][i1[j]]
 *   + b2[j] * f[c][i2[j]] (added left to right) for the 3 channel planes f[3, K], img[3, size].
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <stdint.h>

#define SUB 256

static int64_t floordiv(int64_t a, int64_t b) {
    int64_t q = a / b;
    if ((a % b != 0) && ((a < 0) != (b < 0)))
        q -= 1;
    return q;
}

static int get(PyObject *o, Py_buffer *v, Py_ssize_t itemsize, int writable, const char *what) {
    if (PyObject_GetBuffer(o, v, PyBUF_C_CONTIGUOUS | (writable ? PyBUF_WRITABLE : 0)) < 0)
        return -1;
    if (v->itemsize != itemsize) {
        PyErr_Format(PyExc_TypeError, "%s: items of %zd bytes expected", what, itemsize);
        PyBuffer_Release(v);
        return -1;
    }
    return 0;
}

static PyObject *winners(PyObject *self, PyObject *args) {
    Py_ssize_t width, height;
    double far;
    int any_beyond;
    PyObject *oi, *of, *ob, *oz, *ot;
    if (!PyArg_ParseTuple(args, "nndpOOOOO", &width, &height, &far, &any_beyond, &oi, &of, &ob, &oz, &ot))
        return NULL;
    Py_buffer bi, bf, bb, bz, bt;
    if (get(oi, &bi, 8, 0, "tri_i64") < 0) return NULL;
    if (get(of, &bf, 8, 0, "tri_f64") < 0) { PyBuffer_Release(&bi); return NULL; }
    if (get(ob, &bb, 1, 0, "beyond") < 0) { PyBuffer_Release(&bi); PyBuffer_Release(&bf); return NULL; }
    if (get(oz, &bz, 8, 1, "zbuf") < 0) {
        PyBuffer_Release(&bi); PyBuffer_Release(&bf); PyBuffer_Release(&bb); return NULL;
    }
    if (get(ot, &bt, 8, 1, "tbuf") < 0) {
        PyBuffer_Release(&bi); PyBuffer_Release(&bf); PyBuffer_Release(&bb); PyBuffer_Release(&bz); return NULL;
    }
    Py_ssize_t m = bb.len;
    PyObject *result = NULL;
    if (bi.len != m * 20 * 8 || bf.len != m * 4 * 8 || bz.len != width * height * 8 || bt.len != width * height * 8) {
        PyErr_SetString(PyExc_ValueError, "winners: array sizes do not agree");
        goto done;
    }
    const int64_t *ti = (const int64_t *)bi.buf;
    const double *tf = (const double *)bf.buf;
    const uint8_t *beyond = (const uint8_t *)bb.buf;
    double *z = (double *)bz.buf;
    int64_t *tb = (int64_t *)bt.buf;
    Py_BEGIN_ALLOW_THREADS
    for (Py_ssize_t t = 0; t < m; t++) {
        const int64_t *r = ti + t * 20;
        const int64_t X0 = r[0], Y0 = r[1], px0 = r[2], py0 = r[3], si0 = r[4], sj0 = r[5], bw = r[6], bh = r[7];
        const double iz0 = tf[t * 4], A = tf[t * 4 + 1], B = tf[t * 4 + 2], ASUB = tf[t * 4 + 3];
        const int far_test = any_beyond && beyond[t];
        for (int64_t row = 0; row < bh; row++) {
            int64_t lo = 0, hi = bw - 1;
            for (int q = 0; q < 3; q++) {
                const int64_t thr = r[8 + 4 * q], worg = r[9 + 4 * q], sx = r[10 + 4 * q], sy = r[11 + 4 * q];
                const int64_t c = thr - (worg + sy * row);
                if (sx > 0) {
                    int64_t v = floordiv(c, sx) + 1;
                    if (v > lo) lo = v;
                } else if (sx < 0) {
                    int64_t v = -floordiv(-c, sx) - 1;
                    if (v < hi) hi = v;
                }
                if (sx == 0 && c >= 0) hi = -1;
            }
            if (hi < lo) continue;
            const int64_t rpx = px0 + lo * SUB, rpy = py0 + row * SUB;
            const double riz = iz0 + A * (double)(rpx - X0) + B * (double)(rpy - Y0);
            int64_t p = (sj0 + row) * (int64_t)width + si0 + lo;
            for (int64_t k = 0; k <= hi - lo; k++, p++) {
                double fiz = riz + ASUB * (double)k;
                if (far_test && !(fiz * far >= 1.0))
                    fiz = -1.0;
                if (fiz > z[p]) {
                    z[p] = fiz;
                    tb[p] = t;
                } else if (fiz == z[p] && (tb[p] < 0 || t < tb[p])) {
                    tb[p] = t;
                }
            }
        }
    }
    Py_END_ALLOW_THREADS
    result = Py_None;
    Py_INCREF(result);
done:
    PyBuffer_Release(&bi); PyBuffer_Release(&bf); PyBuffer_Release(&bb); PyBuffer_Release(&bz); PyBuffer_Release(&bt);
    return result;
}

static PyObject *resolve(PyObject *self, PyObject *args) {
    Py_ssize_t width;
    PyObject *o[8];
    if (!PyArg_ParseTuple(args, "nOOOOOOOO", &width, &o[0], &o[1], &o[2], &o[3], &o[4], &o[5], &o[6], &o[7]))
        return NULL;
    static const char *names[8] = {"tbuf", "tri_i64", "tri_f64", "wp", "wt", "b0", "b1", "b2"};
    Py_buffer b[8];
    int got = 0;
    PyObject *result = NULL;
    for (; got < 8; got++)
        if (get(o[got], &b[got], 8, got >= 3, names[got]) < 0)
            goto done;
    Py_ssize_t size = b[0].len / 8, m = b[1].len / (7 * 8);
    if (b[2].len != m * 4 * 8 || width <= 0) {
        PyErr_SetString(PyExc_ValueError, "resolve: array sizes do not agree");
        goto done;
    }
    for (int i = 3; i < 8; i++)
        if (b[i].len != size * 8) {
            PyErr_SetString(PyExc_ValueError, "resolve: output arrays must hold width * height items");
            goto done;
        }
    const int64_t *tb = (const int64_t *)b[0].buf, *ti = (const int64_t *)b[1].buf;
    const double *tf = (const double *)b[2].buf;
    int64_t *wp = (int64_t *)b[3].buf, *wt = (int64_t *)b[4].buf;
    double *b0 = (double *)b[5].buf, *b1 = (double *)b[6].buf, *b2 = (double *)b[7].buf;
    Py_ssize_t n = 0;
    int bad = 0;
    Py_BEGIN_ALLOW_THREADS
    for (Py_ssize_t p = 0; p < size; p++) {
        const int64_t t = tb[p];
        if (t < 0)
            continue;
        if (t >= m) { bad = 1; break; }
        const int64_t *r = ti + t * 7;
        const int64_t X0 = r[0], Y0 = r[1], X1 = r[2], Y1 = r[3], X2 = r[4], Y2 = r[5], area = r[6];
        const int64_t spx = (p % width) * SUB + SUB / 2, spy = (p / width) * SUB + SUB / 2;
        const int64_t w1 = (X0 - X2) * (spy - Y2) - (Y0 - Y2) * (spx - X2);
        const int64_t w2 = (X1 - X0) * (spy - Y0) - (Y1 - Y0) * (spx - X0);
        const int64_t w0 = area - w1 - w2;
        const double ar = tf[t * 4];
        const double q0 = ((double)w0 / ar) * tf[t * 4 + 1];
        const double q1 = ((double)w1 / ar) * tf[t * 4 + 2];
        const double q2 = ((double)w2 / ar) * tf[t * 4 + 3];
        const double izw = q0 + q1 + q2;
        wp[n] = p;
        wt[n] = t;
        b0[n] = q0 / izw;
        b1[n] = q1 / izw;
        b2[n] = q2 / izw;
        n++;
    }
    Py_END_ALLOW_THREADS
    if (bad) {
        PyErr_SetString(PyExc_ValueError, "resolve: a winner index is out of range");
        goto done;
    }
    result = PyLong_FromSsize_t(n);
done:
    for (int i = 0; i < got; i++)
        PyBuffer_Release(&b[i]);
    return result;
}

static PyObject *box_downsample(PyObject *self, PyObject *args) {
    Py_ssize_t C, H, W, n;
    PyObject *oi, *oo;
    if (!PyArg_ParseTuple(args, "OnnnnO", &oi, &C, &H, &W, &n, &oo))
        return NULL;
    Py_buffer bi, bo;
    if (get(oi, &bi, 8, 0, "planes") < 0) return NULL;
    if (get(oo, &bo, 8, 1, "out") < 0) { PyBuffer_Release(&bi); return NULL; }
    PyObject *result = NULL;
    if (n < 1 || C < 0 || H < 0 || W < 0 || bi.len != C * H * n * W * n * 8 || bo.len != C * H * W * 8) {
        PyErr_SetString(PyExc_ValueError, "box_downsample: array sizes do not agree");
        goto done;
    }
    const double *in = (const double *)bi.buf;
    double *out = (double *)bo.buf;
    const double nn = (double)(n * n);
    const Py_ssize_t Wn = W * n;
    Py_BEGIN_ALLOW_THREADS
    for (Py_ssize_t c = 0; c < C; c++)
        for (Py_ssize_t y = 0; y < H; y++)
            for (Py_ssize_t x = 0; x < W; x++) {
                const double *blk = in + ((c * H + y) * n) * Wn + x * n;
                double s = 0.0;
                for (Py_ssize_t dy = 0; dy < n; dy++) {
                    const double *row = blk + dy * Wn;
                    double sx = n > 1 ? row[0] + row[1] : row[0];
                    for (Py_ssize_t dx = 2; dx < n; dx++)
                        sx += row[dx];
                    s = dy == 0 ? sx : s + sx;
                }
                out[(c * H + y) * W + x] = n > 1 ? s / nn : s;
            }
    Py_END_ALLOW_THREADS
    result = Py_None;
    Py_INCREF(result);
done:
    PyBuffer_Release(&bi);
    PyBuffer_Release(&bo);
    return result;
}

static PyObject *interp_scatter(PyObject *self, PyObject *args) {
    PyObject *o[9];
    if (!PyArg_ParseTuple(args, "OOOOOOOOO", &o[0], &o[1], &o[2], &o[3], &o[4], &o[5], &o[6], &o[7], &o[8]))
        return NULL;
    static const char *names[9] = {"f", "i0", "i1", "i2", "b0", "b1", "b2", "pix", "img"};
    Py_buffer b[9];
    int got = 0;
    PyObject *result = NULL;
    for (; got < 9; got++)
        if (get(o[got], &b[got], 8, got == 8, names[got]) < 0)
            goto done;
    const Py_ssize_t K = b[0].len / (3 * 8), n = b[1].len / 8, size = b[8].len / (3 * 8);
    if (b[0].len != K * 3 * 8 || b[8].len != size * 3 * 8) {
        PyErr_SetString(PyExc_ValueError, "interp_scatter: f and img must be 3 channel planes");
        goto done;
    }
    for (int i = 2; i < 8; i++)
        if (b[i].len != n * 8) {
            PyErr_SetString(PyExc_ValueError, "interp_scatter: per-sample arrays differ in length");
            goto done;
        }
    const double *f = (const double *)b[0].buf;
    const int64_t *i0 = (const int64_t *)b[1].buf, *i1 = (const int64_t *)b[2].buf, *i2 = (const int64_t *)b[3].buf;
    const double *b0 = (const double *)b[4].buf, *b1 = (const double *)b[5].buf, *b2 = (const double *)b[6].buf;
    const int64_t *pix = (const int64_t *)b[7].buf;
    double *img = (double *)b[8].buf;
    for (Py_ssize_t j = 0; j < n; j++)
        if (i0[j] < 0 || i0[j] >= K || i1[j] < 0 || i1[j] >= K || i2[j] < 0 || i2[j] >= K || pix[j] < 0
            || pix[j] >= size) {
            PyErr_SetString(PyExc_IndexError, "interp_scatter: an index is out of range");
            goto done;
        }
    Py_BEGIN_ALLOW_THREADS
    for (int c = 0; c < 3; c++) {
        const double *fc = f + c * K;
        double *ic = img + c * size;
        for (Py_ssize_t j = 0; j < n; j++)
            ic[pix[j]] = b0[j] * fc[i0[j]] + b1[j] * fc[i1[j]] + b2[j] * fc[i2[j]];
    }
    Py_END_ALLOW_THREADS
    result = Py_None;
    Py_INCREF(result);
done:
    for (int i = 0; i < got; i++)
        PyBuffer_Release(&b[i]);
    return result;
}

static PyMethodDef methods[] = {
    {"interp_scatter", interp_scatter, METH_VARARGS, "Gouraud interpolation of lit colours into the image."},
    {"box_downsample", box_downsample, METH_VARARGS, "The n x n box filter of raster.box_downsample_planes."},
    {"winners", winners, METH_VARARGS, "Scan-convert triangles into a depth and winner buffer."},
    {"resolve", resolve, METH_VARARGS, "The winners in sample order with their barycentrics."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_fastraster",
                                    "Native scan conversion and depth test (rendering/raster.py is the reference).",
                                    -1, methods};

PyMODINIT_FUNC PyInit__fastraster(void) { return PyModule_Create(&module); }
