/* imud._kernels: the generic per-read arithmetic of the sample clock and the pipeline, one call
 * each where NumPy takes several.
 *
 * Why C: a FIFO read of a few dozen samples costs imud a few hundred microseconds, most of it
 * the fixed cost of NumPy calls on small arrays after a sleep (docs/performance.md, "A compiled
 * build of the hot modules: no gain"). Each function here replaces a run of such calls with one.
 * Each has a NumPy twin in the module that calls it, which is the reference: the results are
 * bit for bit the same (tests/test_compiled.py), so the build is compiled with
 * -ffp-contract=off (no fused multiply-add, which aarch64 would otherwise use and NumPy does
 * not).
 *
 * Arrays come in as writable buffers (the buffer protocol), so no NumPy headers are needed to
 * build this: a C compiler and Python's own headers are enough.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include <math.h>
#include <stdint.h>
#include <string.h>

#include "_buffers.h"

/* stamps(out, s, b, k0, period, corr, last_ts, follow, slew_room)
 *
 * The stamps of samples k0 .. k0 + n - 1 (n: out's length in int64s) on the fitted line
 * t(k) = s + period * (k - b), moved by `corr`; when `follow`, steered from `last_ts` (the
 * previous stamp, sample k0 - 1) by at most `slew_room` ns a sample; rounded half to even; and
 * strictly after `last_ts` when it is not None. SampleClock.update's NumPy tail, in the same
 * operations and order. */
static PyObject *stamps(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    if (nargs != 9) {
        PyErr_SetString(PyExc_TypeError, "stamps() takes 9 arguments");
        return NULL;
    }
    double s = PyFloat_AsDouble(args[1]);
    double b = PyFloat_AsDouble(args[2]);
    long long k0 = PyLong_AsLongLong(args[3]);
    double period = PyFloat_AsDouble(args[4]);
    double corr = PyFloat_AsDouble(args[5]);
    int has_last = args[6] != Py_None;
    long long last = has_last ? PyLong_AsLongLong(args[6]) : 0;
    int follow = PyObject_IsTrue(args[7]);
    double room1 = PyFloat_AsDouble(args[8]);
    if (PyErr_Occurred())
        return NULL;
    Py_buffer out;
    if (!get_buffer(args[0], &out, 0, 1, "stamps out"))
        return NULL;
    Py_ssize_t n = out.len / (Py_ssize_t)sizeof(int64_t);
    int64_t *t = (int64_t *)out.buf;
    double flast = (double)last;
    for (Py_ssize_t i = 0; i < n; i++) {
        double k = (double)(k0 + i);
        double est = (s + period * (k - b)) + corr;
        if (follow) {
            double step = (double)(i + 1);
            double cont = flast + step * period;
            double room = step * room1;
            double d = est - cont;
            d = d < -room ? -room : d;
            d = d > room ? room : d;
            est = cont + d;
        }
        /* NumPy casts a non-finite or out-of-range float to INT64_MIN on x86-64; C leaves it
         * undefined (aarch64 saturates), so it is spelled out */
        const double r = rint(est);
        t[i] = (r >= -9223372036854775808.0 && r < 9223372036854775808.0) ? (int64_t)r : INT64_MIN;
    }
    if (has_last && n && t[0] <= last) {
        for (Py_ssize_t i = 0; i < n; i++) {
            int64_t floor = last + 1 + i;
            if (t[i] < floor)
                t[i] = floor;
        }
    }
    PyBuffer_Release(&out);
    Py_RETURN_NONE;
}

/* tick_steps(ticks, modulo) -> (largest step, sum of steps)
 *
 * A chip counter's steps between consecutive samples of a batch, each taken modulo the
 * counter's wrap: the sample clock's tick-ratio learning. `ticks` holds int64s. */
static PyObject *tick_steps(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    if (nargs != 2) {
        PyErr_SetString(PyExc_TypeError, "tick_steps() takes 2 arguments");
        return NULL;
    }
    long long mod = PyLong_AsLongLong(args[1]);
    if (PyErr_Occurred())
        return NULL;
    if (mod <= 0) {
        PyErr_SetString(PyExc_ValueError, "tick_steps: modulo must be positive");
        return NULL;
    }
    Py_buffer in;
    if (PyObject_GetBuffer(args[0], &in, PyBUF_C_CONTIGUOUS | PyBUF_FORMAT) < 0)
        return NULL;
    if (!is_native(&in, 8, "ql")) {
        PyBuffer_Release(&in);
        PyErr_SetString(PyExc_TypeError, "tick_steps: ticks must be native int64s");
        return NULL;
    }
    Py_ssize_t n = in.len / (Py_ssize_t)sizeof(int64_t);
    const int64_t *v = (const int64_t *)in.buf;
    long long largest = 0, sum = 0;
    for (Py_ssize_t i = 1; i < n; i++) {
        /* wrapping like NumPy's int64 (signed overflow is undefined in C) */
        long long d = (long long)((uint64_t)v[i] - (uint64_t)v[i - 1]) % mod;
        if (d < 0)
            d += mod; /* Python's and NumPy's modulo take the divisor's sign */
        if (d > largest)
            largest = d;
        sum += d;
    }
    PyBuffer_Release(&in);
    return Py_BuildValue("(LL)", largest, sum);
}

/* reaches(data, full_scale) -> bool
 *
 * Whether any int32 count in `data` (one or two dimensions, any strides: a driver's columns of
 * a wider record come as views) is at or beyond +-full_scale: a sensor at its range's end (the
 * pipeline's saturation flag, whose per-sample work runs only when this says so). */
static PyObject *reaches(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    if (nargs != 2) {
        PyErr_SetString(PyExc_TypeError, "reaches() takes 2 arguments");
        return NULL;
    }
    double fs = PyFloat_AsDouble(args[1]);
    if (PyErr_Occurred())
        return NULL;
    Py_buffer in;
    if (PyObject_GetBuffer(args[0], &in, PyBUF_STRIDES | PyBUF_FORMAT) < 0)
        return NULL;
    if (!is_native(&in, 4, "il") || in.ndim < 1 || in.ndim > 2) {
        PyBuffer_Release(&in);
        PyErr_SetString(PyExc_TypeError,
                        "reaches: data must be native int32 counts in one or two dimensions");
        return NULL;
    }
    const Py_ssize_t rows = in.shape[0], cols = in.ndim == 2 ? in.shape[1] : 1;
    const Py_ssize_t rs = in.strides[0], cs = in.ndim == 2 ? in.strides[1] : 0;
    const char *base = (const char *)in.buf;
    int32_t lo = 0, hi = 0;
    for (Py_ssize_t i = 0; i < rows; i++) {
        const char *row = base + i * rs;
        for (Py_ssize_t j = 0; j < cols; j++) {
            int32_t v;
            memcpy(&v, row + j * cs, sizeof v);
            lo = v < lo ? v : lo;
            hi = v > hi ? v : hi;
        }
    }
    PyBuffer_Release(&in);
    return PyBool_FromLong((double)hi >= fs || (double)lo <= -fs);
}

/* bracket(a_t, seq, t, jj, w, base) -> int
 *
 * Where each time of t (ascending) falls among another die's sample times a_t (ascending, at
 * least two; their seqs in seq): jj, the index of the sample at or before it, held to the
 * pairs there are (0 .. m - 2); w, how far along that pair it lies, held to [0, 1]; base,
 * whether the pair brackets it and is two consecutive samples. Returns jj's last value. The
 * align stage's _Follower.at, in the same operations. */
static PyObject *bracket(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    if (nargs != 6) {
        PyErr_SetString(PyExc_TypeError, "bracket() takes 6 arguments");
        return NULL;
    }
    Py_buffer at, sq, tt, jb, wb, bb;
    if (!get_buffer(args[0], &at, 16, 0, "bracket a_t"))
        return NULL;
    const Py_ssize_t m = at.len / 8;
    if (!get_buffer(args[1], &sq, m * 8, 0, "bracket seq")) {
        PyBuffer_Release(&at);
        return NULL;
    }
    if (!get_buffer(args[2], &tt, 0, 0, "bracket t")) {
        PyBuffer_Release(&sq);
        PyBuffer_Release(&at);
        return NULL;
    }
    const Py_ssize_t n = tt.len / 8;
    int got = 0;
    if (get_buffer(args[3], &jb, n * 8, 1, "bracket jj")) {
        got = 1;
        if (get_buffer(args[4], &wb, n * 8, 1, "bracket w")) {
            got = 2;
            if (get_buffer(args[5], &bb, n, 1, "bracket base"))
                got = 3;
        }
    }
    if (got < 3) {
        if (got > 1) PyBuffer_Release(&wb);
        if (got > 0) PyBuffer_Release(&jb);
        PyBuffer_Release(&tt);
        PyBuffer_Release(&sq);
        PyBuffer_Release(&at);
        return NULL;
    }
    const int64_t *a = (const int64_t *)at.buf, *seq = (const int64_t *)sq.buf;
    const int64_t *t = (const int64_t *)tt.buf;
    int64_t *jj = (int64_t *)jb.buf;
    double *w = (double *)wb.buf;
    uint8_t *base = (uint8_t *)bb.buf;
    Py_ssize_t j = -1; /* the newest sample at or before t[i]: t ascends, so it only moves on */
    for (Py_ssize_t i = 0; i < n; i++) {
        if (i && t[i] < t[i - 1])
            j = -1; /* (not ascending after all: search from the start, as a bisection would) */
        while (j + 1 < m && a[j + 1] <= t[i])
            j++;
        const Py_ssize_t k = j < 0 ? 0 : (j > m - 2 ? m - 2 : j);
        const int64_t t0 = a[k], t1 = a[k + 1];
        double x = (double)(t[i] - t0) / (double)(t1 - t0);
        x = x < 0.0 ? 0.0 : x;
        x = x > 1.0 ? 1.0 : x;
        jj[i] = k;
        w[i] = x;
        base[i] = j >= 0 && t[i] <= a[m - 1] && seq[k + 1] - seq[k] == 1;
    }
    const long long last = n ? (long long)jj[n - 1] : 0;
    PyBuffer_Release(&bb);
    PyBuffer_Release(&wb);
    PyBuffer_Release(&jb);
    PyBuffer_Release(&tt);
    PyBuffer_Release(&sq);
    PyBuffer_Release(&at);
    return PyLong_FromLongLong(last);
}

/* lerp(v, inv, jj, w, base, out, bad) -> bool
 *
 * One channel of another die at the times bracket() placed: out[i] = v[jj] + w (v[jj+1] -
 * v[jj]) per component (v float64, m rows of c components; out n rows), and bad[i] where the
 * pair does not bracket the time (base False) or either sample is invalid (inv). Returns
 * whether any is bad. */
static PyObject *lerp(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    if (nargs != 7) {
        PyErr_SetString(PyExc_TypeError, "lerp() takes 7 arguments");
        return NULL;
    }
    Py_buffer vb, ib, jb, wb, bb, ob, xb;
    Py_buffer *views[7] = {&vb, &ib, &jb, &wb, &bb, &ob, &xb};
    int got = 0;
    for (; got < 7; got++) {
        if (!get_buffer(args[got], views[got], 0, got >= 5, "lerp"))
            break;
    }
    if (got < 7) {
        while (got--)
            PyBuffer_Release(views[got]);
        return NULL;
    }
    const Py_ssize_t m = ib.len, n = jb.len / 8;
    const Py_ssize_t c = m ? vb.len / 8 / m : 0;
    const char *err = NULL;
    if (m < 2 || vb.len != m * c * 8 || c < 1)
        err = "lerp: v and inv disagree on the samples";
    else if (wb.len < n * 8 || bb.len < n || xb.len < n || ob.len != n * c * 8)
        err = "lerp: outputs sized for another batch";
    const double *v = (const double *)vb.buf, *w = (const double *)wb.buf;
    const uint8_t *inv = (const uint8_t *)ib.buf, *base = (const uint8_t *)bb.buf;
    const int64_t *jj = (const int64_t *)jb.buf;
    double *out = (double *)ob.buf;
    uint8_t *bad = (uint8_t *)xb.buf;
    int any_bad = 0;
    for (Py_ssize_t i = 0; err == NULL && i < n; i++) {
        const int64_t k = jj[i];
        if (k < 0 || k > m - 2) {
            err = "lerp: an index outside the samples";
            break;
        }
        const double *lo = v + k * c, *hi = lo + c;
        for (Py_ssize_t j = 0; j < c; j++)
            out[i * c + j] = lo[j] + w[i] * (hi[j] - lo[j]);
        bad[i] = !(base[i] && !inv[k] && !inv[k + 1]);
        any_bad |= bad[i];
    }
    for (int i = 6; i >= 0; i--)
        PyBuffer_Release(views[i]);
    if (err != NULL) {
        PyErr_SetString(PyExc_ValueError, err);
        return NULL;
    }
    return PyBool_FromLong(any_bad);
}

/* pack(prefix, t, sample_flags, channels) -> bytes
 *
 * A wire batch's bytes after its header and name (which `prefix` holds): the int64 stamps,
 * the uint32 sample flags (zeros when None), then each channel's values as float32, in the
 * order given. Native byte order: the caller uses it only on a little-endian machine (the wire
 * format's). Channels must be C-contiguous float64 or float32 (TypeError or BufferError
 * otherwise: the caller then packs them with NumPy). */
#define PACK_MAX 16
static PyObject *pack(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    (void)self;
    if (nargs != 4 || !PyTuple_Check(args[3])) {
        PyErr_SetString(PyExc_TypeError, "pack(prefix, t, sample_flags, channels: tuple)");
        return NULL;
    }
    const Py_ssize_t k = PyTuple_GET_SIZE(args[3]);
    if (k > PACK_MAX) {
        PyErr_SetString(PyExc_ValueError, "pack: too many channels");
        return NULL;
    }
    Py_buffer pre, tb, sb, ch[PACK_MAX];
    int have_sf = args[2] != Py_None, got = 0, ok = 0;
    PyObject *out = NULL;
    if (PyObject_GetBuffer(args[0], &pre, PyBUF_C_CONTIGUOUS) < 0)
        return NULL;
    if (PyObject_GetBuffer(args[1], &tb, PyBUF_C_CONTIGUOUS | PyBUF_FORMAT) < 0)
        goto release_pre;
    if (!is_native(&tb, 8, "ql")) {
        PyErr_SetString(PyExc_TypeError, "pack: stamps must be int64");
        goto release_t;
    }
    const Py_ssize_t n = tb.len / 8;
    if (have_sf) {
        if (PyObject_GetBuffer(args[2], &sb, PyBUF_C_CONTIGUOUS) < 0)
            goto release_t;
        if (sb.itemsize != 4 || sb.len != 4 * n) {
            PyErr_SetString(PyExc_TypeError, "pack: sample flags must be n uint32s");
            goto release_sf;
        }
    }
    Py_ssize_t size = pre.len + 12 * n;
    for (; got < k; got++) {
        Py_buffer *v = &ch[got];
        if (PyObject_GetBuffer(PyTuple_GET_ITEM(args[3], got), v,
                               PyBUF_C_CONTIGUOUS | PyBUF_FORMAT) < 0)
            goto release_ch;
        const char *f = v->format ? v->format : "";
        if ((f[0] == '<' && !PY_BIG_ENDIAN) || f[0] == '=' || f[0] == '@')
            f++;
        if (!((f[0] == 'd' && v->itemsize == 8) || (f[0] == 'f' && v->itemsize == 4)) || f[1]) {
            PyErr_SetString(PyExc_TypeError, "pack: channels must be float64 or float32");
            got++;
            goto release_ch;
        }
        size += 4 * (v->len / v->itemsize);
    }
    out = PyBytes_FromStringAndSize(NULL, size);
    if (out == NULL)
        goto release_ch;
    char *w = PyBytes_AS_STRING(out);
    memcpy(w, pre.buf, pre.len);
    w += pre.len;
    memcpy(w, tb.buf, 8 * n);
    w += 8 * n;
    if (have_sf)
        memcpy(w, sb.buf, 4 * n);
    else
        memset(w, 0, 4 * n);
    w += 4 * n;
    for (Py_ssize_t i = 0; i < k; i++) {
        const Py_ssize_t m = ch[i].len / ch[i].itemsize;
        if (ch[i].itemsize == 4) {
            memcpy(w, ch[i].buf, 4 * m);
        } else {
            const double *src = (const double *)ch[i].buf;
            float *dst = (float *)w; /* bytes objects are aligned for any scalar */
            for (Py_ssize_t j = 0; j < m; j++)
                dst[j] = (float)src[j];
        }
        w += 4 * m;
    }
    ok = 1;
release_ch:
    while (got-- > 0)
        PyBuffer_Release(&ch[got]);
release_sf:
    if (have_sf)
        PyBuffer_Release(&sb);
release_t:
    PyBuffer_Release(&tb);
release_pre:
    PyBuffer_Release(&pre);
    if (!ok)
        Py_CLEAR(out);
    return out;
}

/* The quaternion product q x e as L(q) e (orient.ekf._left). */
static void quat_left(const double q[4], const double e[4], double out[4]) {
    const double w = q[0], x = q[1], y = q[2], z = q[3];
    out[0] = w * e[0] - x * e[1] - y * e[2] - z * e[3];
    out[1] = x * e[0] + w * e[1] - z * e[2] + y * e[3];
    out[2] = y * e[0] + z * e[1] + w * e[2] - x * e[3];
    out[3] = z * e[0] - y * e[1] + x * e[2] + w * e[3];
}

/* orient_chunk(gyro, b, dt, q, accel, steps, q_out, qq, qqa, kqqa, p, c_out) -> (kn, k)
 *
 * The orientation filter's integration of one chunk (orient.ekf.OrientationFilter._chunk, its
 * NumPy twin): each sample's orientation from the gyro less its bias (first order, from the
 * chunk's start) into q_out (m x 4); the interval's sums of q outer q (qq, 16), and with a valid
 * accelerometer row of (q outer q) outer a (qqa, 16 x 3) and the same weighted by the sample's
 * index in the interval (kqqa; the interval had `steps` samples before the chunk). The
 * orientation at the chunk's end (second order: Bortz's coning term), unit, goes into q; it
 * returns the sum of the valid rows' indices and their number. gyro and accel must be float64
 * and C-contiguous (TypeError or ValueError otherwise: the caller converts and calls again). A non-finite gyro value turns nothing. Given c_out
 * (m x 6, else None), each of its rows gets the rotation error's covariance from p (8 x 8):
 * xx, xy, xz, yy, yz, zz. Equal to the twin to rounding (matrix products sum in another
 * order): tests/test_compiled.py. */
static PyObject *orient_chunk(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    (void)self;
    if (nargs != 12) {
        PyErr_SetString(PyExc_TypeError, "orient_chunk() takes 12 arguments");
        return NULL;
    }
    const double dt = PyFloat_AsDouble(args[2]);
    const double steps0 = PyFloat_AsDouble(args[5]);
    if (PyErr_Occurred())
        return NULL;
    const int has_accel = args[4] != Py_None;
    const int has_cov = args[11] != Py_None;
    Py_buffer gb, bb, qb, ab, ob, s1, s2, s3, pb, cb;
    Py_buffer *views[10] = {&gb, &bb, &qb, &ob, &s1, &s2, &s3, &pb, &ab, &cb};
    PyObject *objs[10] = {args[0], args[1], args[3], args[6],  args[7],
                          args[8], args[9], args[10], args[4], args[11]};
    const int writable[10] = {0, 0, 1, 1, 1, 1, 1, 0, 0, 1};
    const int present[10] = {1, 1, 1, 1, 1, 1, 1, 1, has_accel, has_cov};
    int got = 0;
    for (; got < 10; got++) {
        if (!present[got]) {
            views[got]->obj = NULL;
            continue;
        }
        const int input = got == 0 || got == 8; /* gyro, accel: the caller's arrays */
        if (input ? !get_f64(objs[got], views[got], "orient_chunk")
                  : !get_buffer(objs[got], views[got], 0, writable[got], "orient_chunk"))
            break;
    }
    PyObject *result = NULL;
    const char *err = NULL;
    if (got < 10)
        goto done;
    const Py_ssize_t m = gb.len / 24;
    if (gb.len != m * 24 || bb.len != 24 || qb.len != 32 || ob.len != m * 32 || s1.len != 128 ||
        s2.len != 384 || s3.len != 384 || (has_accel && ab.len != m * 24) || pb.len != 512 ||
        (has_cov && cb.len != m * 48)) {
        err = "orient_chunk: arrays of the wrong sizes";
        goto done;
    }
    const double *g = (const double *)gb.buf, *b = (const double *)bb.buf;
    const double *a = has_accel ? (const double *)ab.buf : NULL;
    double q[4];
    memcpy(q, qb.buf, sizeof q);
    double *qo = (double *)ob.buf, *qq = (double *)s1.buf;
    double *qqa = (double *)s2.buf, *kqqa = (double *)s3.buf;
    double c[3] = {0, 0, 0}, mm[3][3] = {{0}};
    double kn = 0.0;
    long k = 0;
    for (Py_ssize_t i = 0; i < m; i++) {
        double th[3], prev[3];
        for (int d = 0; d < 3; d++) {
            const double v = (g[3 * i + d] - b[d]) * dt;
            th[d] = isfinite(v) ? v : 0.0;
            c[d] += th[d];
            prev[d] = c[d] - th[d];
        }
        for (int r = 0; r < 3; r++)
            for (int s = 0; s < 3; s++)
                mm[r][s] += prev[r] * th[s];
        const double t2 = c[0] * c[0] + c[1] * c[1] + c[2] * c[2];
        const double tn = sqrt(t2), half = 0.5 * tn;
        const double sc = sin(half) / (tn + 1e-300);
        const double e[4] = {cos(half), c[0] * sc, c[1] * sc, c[2] * sc};
        double *qk = qo + 4 * i;
        quat_left(q, e, qk);
        double q2[16];
        for (int r = 0; r < 4; r++)
            for (int s = 0; s < 4; s++)
                q2[4 * r + s] = qk[r] * qk[s];
        for (int p = 0; p < 16; p++)
            qq[p] += q2[p];
        if (has_accel && !isnan(a[3 * i])) {
            const double idx = (double)i + steps0;
            for (int p = 0; p < 16; p++)
                for (int d = 0; d < 3; d++) {
                    qqa[3 * p + d] += q2[p] * a[3 * i + d];
                    kqqa[3 * p + d] += q2[p] * (a[3 * i + d] * idx);
                }
            kn += idx;
            k++;
        }
    }
    const double x = c[0] + 0.5 * (mm[1][2] - mm[2][1]);
    const double y = c[1] + 0.5 * (mm[2][0] - mm[0][2]);
    const double z = c[2] + 0.5 * (mm[0][1] - mm[1][0]);
    const double tn = sqrt(x * x + y * y + z * z);
    const double sc = tn > 1e-12 ? sin(0.5 * tn) / tn : 0.5;
    const double e[4] = {cos(0.5 * tn), x * sc, y * sc, z * sc};
    double qn[4];
    quat_left(q, e, qn);
    const double norm = sqrt(qn[0] * qn[0] + qn[1] * qn[1] + qn[2] * qn[2] + qn[3] * qn[3]);
    if (has_cov) {
        const double *p = (const double *)pb.buf;
        double *co = (double *)cb.buf;
        const double row[6] = {p[0], p[1], p[2], p[9], p[10], p[18]};
        for (Py_ssize_t i = 0; i < m; i++)
            memcpy(co + 6 * i, row, sizeof row);
    }
    double *qw = (double *)qb.buf;
    for (int d = 0; d < 4; d++)
        qw[d] = qn[d] / norm;
    result = Py_BuildValue("(dl)", kn, k);
done:
    while (got-- > 0)
        if (views[got]->obj != NULL)
            PyBuffer_Release(views[got]);
    if (err != NULL) {
        PyErr_SetString(PyExc_ValueError, err);
        Py_CLEAR(result);
    }
    return result;
}

/* --- the orientation filter's correction (orient.kalman, each function's NumPy twin) --- */

#define NS 8 /* error states: world rotation 3, gyro bias 3, horizontal linear acceleration 2 */

/* The rotation-matrix sum (3 x 3, row-major) from a sum of q outer q read with `stride`
 * doubles between its 16 entries (kalman.FORM: off-diagonal products taken from both halves). */
static void rot_from_qq(const double *e, int stride, double r[9]) {
#define E(a, b) e[stride * (4 * (a) + (b))]
    const double ww = E(0, 0), xx = E(1, 1), yy = E(2, 2), zz = E(3, 3);
    const double xy = E(1, 2) + E(2, 1), wz = E(0, 3) + E(3, 0), xz = E(1, 3) + E(3, 1);
    const double wy = E(0, 2) + E(2, 0), yz = E(2, 3) + E(3, 2), wx = E(0, 1) + E(1, 0);
#undef E
    r[0] = ww + xx - yy - zz;
    r[1] = xy - wz;
    r[2] = xz + wy;
    r[3] = xy + wz;
    r[4] = ww - xx + yy - zz;
    r[5] = yz - wx;
    r[6] = xz - wy;
    r[7] = yz + wx;
    r[8] = ww - xx - yy + zz;
}

/* Buffers of float64s of the given sizes (in doubles); raises ValueError naming `what`. */
static int get_doubles(PyObject *const *objs, Py_buffer *views, const Py_ssize_t *sizes,
                       const int *writable, int count, const char *what) {
    for (int i = 0; i < count; i++) {
        if (!get_buffer(objs[i], &views[i], 0, writable[i], what)) {
            while (i-- > 0)
                PyBuffer_Release(&views[i]);
            return 0;
        }
        const Py_ssize_t need = sizes[i] * (Py_ssize_t)sizeof(double);
        if (views[i].len != need) {
            PyErr_Format(PyExc_ValueError, "%s: argument %d holds %zd bytes, need %zd", what,
                         i, views[i].len, need);
            for (int j = i; j >= 0; j--)
                PyBuffer_Release(&views[j]);
            return 0;
        }
    }
    return 1;
}

static void release_all(Py_buffer *views, int count) {
    while (count-- > 0)
        PyBuffer_Release(&views[count]);
}

static void force_sums_core(const double *qqa, const double *kqqa, double out[6]) {
    for (int i = 0; i < 6; i++)
        out[i] = 0.0;
    for (int s = 0; s < 2; s++) {
        const double *src = s ? kqqa : qqa;
        for (int j = 0; j < 3; j++) {
            double r[9];
            rot_from_qq(src + j, 3, r);
            for (int i = 0; i < 3; i++)
                out[3 * s + i] += r[3 * i + j];
        }
    }
}

/* orient_sums(qqa, kqqa) -> (6 floats): an interval's sums of rotated specific force, plain
 * then index-weighted, from its (q outer q) outer a sums (16 x 3 each). kalman.force_sums. */
static PyObject *orient_sums(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    (void)self;
    if (nargs != 2) {
        PyErr_SetString(PyExc_TypeError, "orient_sums() takes 2 arguments");
        return NULL;
    }
    Py_buffer v[2];
    const Py_ssize_t sizes[2] = {48, 48};
    const int wr[2] = {0, 0};
    if (!get_doubles(args, v, sizes, wr, 2, "orient_sums"))
        return NULL;
    double out[6];
    force_sums_core(v[0].buf, v[1].buf, out);
    release_all(v, 2);
    return Py_BuildValue("(dddddd)", out[0], out[1], out[2], out[3], out[4], out[5]);
}

static void propagate_core(double *p, const double *qq, double scale, double rho,
                           const double *qd, double t, double lvar, double *a) {
    double turn[9];
    rot_from_qq(qq, 1, turn);
    double phi[NS][NS] = {{0}}, tmp[NS][NS];
    for (int i = 0; i < NS; i++)
        phi[i][i] = 1.0;
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++)
            phi[i][3 + j] = -(turn[3 * i + j] * scale);
    phi[6][6] = phi[7][7] = rho;
    for (int i = 0; i < NS; i++)
        for (int j = 0; j < NS; j++) {
            double acc = 0.0;
            for (int k = 0; k < NS; k++)
                acc += phi[i][k] * p[NS * k + j];
            tmp[i][j] = acc;
        }
    for (int i = 0; i < NS; i++)
        for (int j = 0; j < NS; j++) {
            double acc = 0.0;
            for (int k = 0; k < NS; k++)
                acc += tmp[i][k] * phi[j][k];
            p[NS * i + j] = acc;
        }
    for (int i = 0; i < 6; i++)
        p[NS * i + i] += qd[i] * t;
    const double ql = lvar * (1.0 - rho * rho);
    p[NS * 6 + 6] += ql;
    p[NS * 7 + 7] += ql;
    a[0] *= rho;
    a[1] *= rho;
}

/* orient_propagate(p, qq, scale, rho, q_density, t, linear_var, a): p = phi p phi^T + Q in
 * place, phi the identity with -scale x (the rotation sum from qq) in the rotation-bias block
 * and rho on the linear acceleration's diagonal; the linear acceleration a (2) decays by rho in
 * place. kalman.propagate. */
static PyObject *orient_propagate(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    (void)self;
    if (nargs != 8) {
        PyErr_SetString(PyExc_TypeError, "orient_propagate() takes 8 arguments");
        return NULL;
    }
    const double scale = PyFloat_AsDouble(args[2]);
    const double rho = PyFloat_AsDouble(args[3]);
    const double t = PyFloat_AsDouble(args[5]);
    const double lvar = PyFloat_AsDouble(args[6]);
    if (PyErr_Occurred())
        return NULL;
    Py_buffer v[4];
    PyObject *objs[4] = {args[0], args[1], args[4], args[7]};
    const Py_ssize_t sizes[4] = {NS * NS, 16, NS, 2};
    const int wr[4] = {1, 0, 0, 1};
    if (!get_doubles(objs, v, sizes, wr, 4, "orient_propagate"))
        return NULL;
    propagate_core(v[0].buf, v[1].buf, scale, rho, v[2].buf, t, lvar, v[3].buf);
    release_all(v, 4);
    Py_RETURN_NONE;
}

static double gravity_h_core(const double *p, const double *qq, double scale, double g,
                             double *h) {
    double turn[9];
    rot_from_qq(qq, 1, turn);
    memset(h, 0, 2 * NS * sizeof(double));
    /* gm = [[0, -g, 0], [g, 0, 0]]: gm x = (-g x1, g x0) */
    h[1] = -g;
    h[NS + 0] = g;
    for (int j = 0; j < 3; j++) {
        h[3 + j] = -g * (turn[3 + j] * scale);
        h[NS + 3 + j] = g * (turn[j] * scale);
    }
    h[6] = 1.0;
    h[NS + 7] = 1.0;
    double trace = 0.0;
    for (int r = 0; r < 2; r++) {
        const double *hr = h + NS * r;
        for (int i = 0; i < NS; i++) {
            double acc = 0.0;
            for (int k = 0; k < NS; k++)
                acc += p[NS * i + k] * hr[k];
            trace += hr[i] * acc;
        }
    }
    return trace;
}

/* orient_gravity_h(p, qq, scale, g, h) -> trace(h p h^T): gravity's measurement matrix (2 x 8)
 * into h, its bias columns through scale x (the rotation sum from qq). kalman.gravity_h. */
static PyObject *orient_gravity_h(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    (void)self;
    if (nargs != 5) {
        PyErr_SetString(PyExc_TypeError, "orient_gravity_h() takes 5 arguments");
        return NULL;
    }
    const double scale = PyFloat_AsDouble(args[2]);
    const double g = PyFloat_AsDouble(args[3]);
    if (PyErr_Occurred())
        return NULL;
    Py_buffer v[3];
    PyObject *objs[3] = {args[0], args[1], args[4]};
    const Py_ssize_t sizes[3] = {NS * NS, 16, 2 * NS};
    const int wr[3] = {0, 0, 1};
    if (!get_doubles(objs, v, sizes, wr, 3, "orient_gravity_h"))
        return NULL;
    const double trace = gravity_h_core(v[0].buf, v[1].buf, scale, g, v[2].buf);
    release_all(v, 3);
    return PyFloat_FromDouble(trace);
}

/* The inverse of a d x d (d <= 3) symmetric positive matrix; 0 if singular (kalman.inverse:
 * closed form, positive determinant, up to 2 x 2; a nonzero one for 3 x 3). */
static int small_inverse(int d, const double s[3][3], double inv[3][3]) {
    if (d == 1) {
        if (!(s[0][0] > 0))
            return 0;
        inv[0][0] = 1.0 / s[0][0];
        return 1;
    }
    if (d == 2) {
        const double det = s[0][0] * s[1][1] - s[0][1] * s[1][0];
        if (!(det > 0))
            return 0;
        inv[0][0] = s[1][1] / det;
        inv[0][1] = -s[0][1] / det;
        inv[1][0] = -s[1][0] / det;
        inv[1][1] = s[0][0] / det;
        return 1;
    }
    double c[3][3];
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++) {
            const int i1 = (i + 1) % 3, i2 = (i + 2) % 3, j1 = (j + 1) % 3, j2 = (j + 2) % 3;
            c[i][j] = s[i1][j1] * s[i2][j2] - s[i1][j2] * s[i2][j1];
        }
    const double det = s[0][0] * c[0][0] + s[0][1] * c[0][1] + s[0][2] * c[0][2];
    if (!(det != 0.0) || !isfinite(det))
        return 0;
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++)
            inv[i][j] = c[j][i] / det;
    return 1;
}

/* kalman.update's arithmetic (orient_update's): 1 if accepted. */
static int update_core(double *p, const double *h, int d, const double *y, const double *rd,
                       double gate, long learn, double consistent, double *q, int keep_heading,
                       double *b, double *a, double e[4]) {
    double ph[NS][3], s[3][3], si[3][3], k[NS][3];
    for (int i = 0; i < NS; i++)
        for (int j = 0; j < d; j++) {
            double acc = 0.0;
            for (int m = 0; m < NS; m++)
                acc += p[NS * i + m] * h[NS * j + m];
            ph[i][j] = acc;
        }
    for (int i = 0; i < d; i++)
        for (int j = 0; j < d; j++) {
            double acc = 0.0;
            for (int m = 0; m < NS; m++)
                acc += h[NS * i + m] * ph[m][j];
            s[i][j] = acc + (i == j ? rd[i] : 0.0);
        }
    int ok = small_inverse(d, s, si);
    double nis = 0.0;
    if (ok) {
        for (int i = 0; i < d; i++)
            for (int j = 0; j < d; j++)
                nis += y[i] * si[i][j] * y[j];
        ok = nis <= gate;
    }
    double dx[NS];
    if (ok) {
        for (int i = 0; i < NS; i++)
            for (int j = 0; j < d; j++) {
                double acc = 0.0;
                for (int m = 0; m < d; m++)
                    acc += ph[i][m] * si[m][j];
                k[i][j] = acc;
            }
        if (learn == 4)
            learn = nis <= consistent ? 0 : 3;
        double np_[NS][NS];
        if (learn == 0) {
            for (int i = 0; i < NS; i++)
                for (int j = 0; j < NS; j++) {
                    double acc = 0.0;
                    for (int m = 0; m < d; m++)
                        acc += k[i][m] * ph[j][m];
                    np_[i][j] = p[NS * i + j] - acc;
                }
        } else {
            if (learn == 3) {
                for (int i = 3; i < 6; i++)
                    for (int j = 0; j < d; j++)
                        k[i][j] = 0.0;
            } else {
                /* the world's vertical in the body frame: the third row of R(q) */
                const double qw = q[0], qx = q[1], qy = q[2], qz = q[3];
                const double up[3] = {2 * (qx * qz - qw * qy), 2 * (qy * qz + qw * qx),
                                      1 - 2 * (qx * qx + qy * qy)};
                for (int j = 0; j < d; j++) {
                    const double w = up[0] * k[3][j] + up[1] * k[4][j] + up[2] * k[5][j];
                    for (int i = 0; i < 3; i++) {
                        const double along = up[i] * w;
                        k[3 + i][j] = learn == 2 ? along : k[3 + i][j] - along;
                    }
                }
            }
            if (keep_heading)
                for (int j = 0; j < d; j++)
                    k[2][j] = 0.0;
            double ikh[NS][NS], t1[NS][NS];
            for (int i = 0; i < NS; i++)
                for (int j = 0; j < NS; j++) {
                    double acc = 0.0;
                    for (int m = 0; m < d; m++)
                        acc += k[i][m] * h[NS * m + j];
                    ikh[i][j] = (i == j ? 1.0 : 0.0) - acc;
                }
            for (int i = 0; i < NS; i++)
                for (int j = 0; j < NS; j++) {
                    double acc = 0.0;
                    for (int m = 0; m < NS; m++)
                        acc += ikh[i][m] * p[NS * m + j];
                    t1[i][j] = acc;
                }
            for (int i = 0; i < NS; i++)
                for (int j = 0; j < NS; j++) {
                    double acc = 0.0, acc2 = 0.0;
                    for (int m = 0; m < NS; m++)
                        acc += t1[i][m] * ikh[j][m];
                    for (int m = 0; m < d; m++)
                        acc2 += k[i][m] * rd[m] * k[j][m];
                    np_[i][j] = acc + acc2;
                }
        }
        for (int i = 0; i < NS; i++) {
            double acc = 0.0;
            for (int m = 0; m < d; m++)
                acc += k[i][m] * y[m];
            dx[i] = acc;
        }
        for (int i = 0; i < NS; i++)
            for (int j = 0; j < NS; j++)
                p[NS * i + j] = 0.5 * (np_[i][j] + np_[j][i]);
        for (int i = 0; i < 3; i++)
            b[i] += dx[3 + i];
        a[0] += dx[6];
        a[1] += dx[7];
    }
    e[0] = 1.0;
    e[1] = e[2] = e[3] = 0.0;
    if (ok) {
        /* ekf.OrientationFilter._rotate_world */
        const double th = sqrt(dx[0] * dx[0] + dx[1] * dx[1] + dx[2] * dx[2]);
        const double sc = th > 1e-12 ? sin(0.5 * th) / th : 0.5;
        e[0] = cos(0.5 * th);
        e[1] = dx[0] * sc;
        e[2] = dx[1] * sc;
        e[3] = dx[2] * sc;
        double qn[4];
        quat_left(e, q, qn);
        const double norm =
            sqrt(qn[0] * qn[0] + qn[1] * qn[1] + qn[2] * qn[2] + qn[3] * qn[3]);
        for (int i = 0; i < 4; i++)
            q[i] = qn[i] / norm;
    }
    return ok;
}

/* Up to three floats from a tuple (or any sequence); their number, or -1 with an error set. */
static int small_floats(PyObject *obj, double out[3], const char *what) {
    PyObject *seq = PySequence_Fast(obj, what);
    if (seq == NULL)
        return -1;
    const Py_ssize_t n = PySequence_Fast_GET_SIZE(seq);
    if (n < 1 || n > 3) {
        Py_DECREF(seq);
        PyErr_Format(PyExc_ValueError, "%s: 1 to 3 values", what);
        return -1;
    }
    for (Py_ssize_t i = 0; i < n; i++)
        out[i] = PyFloat_AsDouble(PySequence_Fast_GET_ITEM(seq, i));
    Py_DECREF(seq);
    return PyErr_Occurred() ? -1 : (int)n;
}

/* orient_update(p, h, y, r, gate, learn, consistent, q, keep_heading, b, a)
 *     -> (w, x, y, z) or None
 *
 * kalman.update: a gated Kalman update of p (8 x 8, in place) by the innovation y (a tuple of
 * d <= 3 floats) through h (d x 8) with diagonal noise r (a tuple of d variances). Accepted, it
 * turns the orientation q (4, in place) by the world-frame correction e = exp(dtheta), q = e x q
 * normalised, adds the bias's correction to b (3) and the linear acceleration's to a (2), in
 * place, and returns e; rejected (the chi-squared
 * gate, or a singular innovation covariance), it changes nothing and returns None. learn: 0
 * all, 1 the bias across the body's vertical (from the orientation q), 2 along it, 3 no bias, 4
 * all if the normalised innovation is within `consistent` else no bias. Below "all" the gain of
 * what is left out is zero (and the heading's too with keep_heading) and the covariance takes
 * Joseph's form. */
static PyObject *orient_update(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    (void)self;
    if (nargs != 11) {
        PyErr_SetString(PyExc_TypeError, "orient_update() takes 11 arguments");
        return NULL;
    }
    const double gate = PyFloat_AsDouble(args[4]);
    long learn = PyLong_AsLong(args[5]);
    const double consistent = PyFloat_AsDouble(args[6]);
    const int keep_heading = PyObject_IsTrue(args[8]);
    if (PyErr_Occurred() || keep_heading < 0)
        return NULL;
    double y[3], rd[3];
    const int d = small_floats(args[2], y, "orient_update y");
    if (d < 0)
        return NULL;
    if (small_floats(args[3], rd, "orient_update r") != d) {
        if (!PyErr_Occurred())
            PyErr_SetString(PyExc_ValueError, "orient_update: r and y of one length");
        return NULL;
    }
    Py_buffer v[5];
    PyObject *objs[5] = {args[0], args[1], args[7], args[9], args[10]};
    const Py_ssize_t sizes[5] = {NS * NS, d * NS, 4, 3, 2};
    const int wr[5] = {1, 0, 1, 1, 1};
    if (!get_doubles(objs, v, sizes, wr, 5, "orient_update"))
        return NULL;
    double *p = v[0].buf, *b = v[3].buf, *a = v[4].buf, *q = v[2].buf;
    double e[4];
    const int ok = update_core(p, v[1].buf, d, y, rd, gate, learn, consistent, q, keep_heading,
                               b, a, e);
    release_all(v, 5);
    if (!ok)
        Py_RETURN_NONE;
    return Py_BuildValue("(dddd)", e[0], e[1], e[2], e[3]);
}

/* The correction's scalar state (ekf.OrientationFilter's attributes; NaN for None), in doubles: */
enum {
    CS_LINEAR_VAR, CS_G0, CS_G0_N, CS_ADAPT_N, CS_PREV_YX, CS_PREV_YY, CS_WHITE_VAR, CS_G_VAR,
    CS_DRIFTED_S, CS_REJECTED_S, CS_RISE, CS_RISE_W = CS_RISE + 3, CS_RISE_T, CS_HAS_RISE,
    CS_MEAN, CS_STATE = CS_MEAN + 3
};
/* and its constants (ekf's module constants and the filter's settings): */
enum {
    CP_ACCEL2, CP_LINEAR_TIME, CP_LINEAR_MAX2, CP_RECOVERY_S, CP_STEADY_AFTER, CP_STEADY2,
    CP_ADAPT_GAIN, CP_WHITE_GAIN, CP_G0_GAIN, CP_FLOOR2, CP_DRIFT_SHARE, CP_DRIFT_SIGMAS,
    CP_DRIFT_S, CP_GATE, CP_CONSISTENT, CP_PARAMS
};

/* orient_correct(p, qq, qqa, kqqa, h, q, b, a, q_density, params, st, n, steps, t, kn,
 *                keep_heading) -> 0 accepted, 1 rejected, 2 rejected and the tilt to re-seed
 *
 * One gravity correction at the end of an interval, all of ekf.OrientationFilter._correct
 * but the still windows' and the magnetometer's updates (its twin: _propagate, then
 * _accel_update with kalman's functions): the covariance's propagation, the gravity window
 * under its triangle, the noise levels' learning, the gated update with what it may teach, and
 * the reference |g| and the re-seed's tests. The arrays are updated in place, the scalar state
 * `st` (CS_STATE doubles) too; with 2 the window's mean is in st[CS_MEAN..] for the caller's
 * re-seed. */
static PyObject *orient_correct(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    (void)self;
    if (nargs != 16) {
        PyErr_SetString(PyExc_TypeError, "orient_correct() takes 16 arguments");
        return NULL;
    }
    const double n = PyFloat_AsDouble(args[11]);
    const double steps = PyFloat_AsDouble(args[12]);
    const double t = PyFloat_AsDouble(args[13]);
    const double kn = PyFloat_AsDouble(args[14]);
    const int keep_heading = PyObject_IsTrue(args[15]);
    if (PyErr_Occurred() || keep_heading < 0)
        return NULL;
    if (!(n > 0)) {
        PyErr_SetString(PyExc_ValueError, "orient_correct: an interval with accelerometer samples");
        return NULL;
    }
    Py_buffer v[11];
    const Py_ssize_t sizes[11] = {NS * NS, 16, 48, 48, 2 * NS, 4, 3, 2, NS, CP_PARAMS, CS_STATE};
    const int wr[11] = {1, 0, 0, 0, 1, 1, 1, 1, 0, 0, 1};
    if (!get_doubles(args, v, sizes, wr, 11, "orient_correct"))
        return NULL;
    double *p = v[0].buf, *h = v[4].buf, *q = v[5].buf, *b = v[6].buf, *a = v[7].buf;
    const double *qq = v[1].buf, *qd = v[8].buf, *cp = v[9].buf;
    double *st = v[10].buf;
    const double steps1 = steps > 1.0 ? steps : 1.0;

    /* _propagate */
    const double rho = exp(-t / cp[CP_LINEAR_TIME]);
    propagate_core(p, qq, t / steps1, rho, qd, t, st[CS_LINEAR_VAR], a);

    /* _gravity_window */
    double sums[6];
    force_sums_core(v[2].buf, v[3].buf, sums);
    const double rising[3] = {sums[3] / steps1, sums[4] / steps1, sums[5] / steps1};
    const double w_rise = kn / steps1, w_fall = n - w_rise;
    const int has_prev = st[CS_HAS_RISE] != 0.0;
    double prev[3] = {st[CS_RISE], st[CS_RISE + 1], st[CS_RISE + 2]};
    const double prev_w = st[CS_RISE_W], prev_t = st[CS_RISE_T];
    for (int i = 0; i < 3; i++)
        st[CS_RISE + i] = rising[i];
    st[CS_RISE_W] = w_rise;
    st[CS_RISE_T] = t;
    st[CS_HAS_RISE] = 1.0;
    double mean[3], centre;
    if (!has_prev || !(prev_w + w_fall > 0.0)) {
        for (int i = 0; i < 3; i++)
            mean[i] = sums[i] / n;
        centre = 0.5 * t;
    } else {
        centre = (w_fall * t / 3.0 + prev_w * (t + prev_t / 3.0)) / (w_fall + prev_w);
        const double k = w_fall + prev_w;
        for (int i = 0; i < 3; i++)
            mean[i] = (sums[i] - rising[i] + prev[i]) / k;
    }

    /* _accel_update */
    const double g = sqrt(mean[0] * mean[0] + mean[1] * mean[1] + mean[2] * mean[2]);
    const double g0 = isnan(st[CS_G0]) ? g : st[CS_G0];
    const double tt = n * t / steps1;
    double var = cp[CP_ACCEL2] / tt + (g - g0) * (g - g0);
    const double y[2] = {mean[0] - a[0], mean[1] - a[1]};
    const double yy2 = y[0] * y[0] + y[1] * y[1];
    if (!isnan(st[CS_PREV_YX])) {
        const double dx = y[0] - st[CS_PREV_YX], dy = y[1] - st[CS_PREV_YY];
        st[CS_WHITE_VAR] += cp[CP_WHITE_GAIN] * (0.25 * (dx * dx + dy * dy) - st[CS_WHITE_VAR]);
    }
    st[CS_PREV_YX] = y[0];
    st[CS_PREV_YY] = y[1];
    if (st[CS_WHITE_VAR] > var)
        var = st[CS_WHITE_VAR];
    const double hph = gravity_h_core(p, qq, centre / steps1, g, h);
    const double excess = 0.5 * (yy2 - hph) - var;
    st[CS_ADAPT_N] += 1.0;
    const double gain = 1.0 / st[CS_ADAPT_N] > cp[CP_ADAPT_GAIN] ? 1.0 / st[CS_ADAPT_N]
                                                                  : cp[CP_ADAPT_GAIN];
    double lv = st[CS_LINEAR_VAR] + gain * excess;
    lv = lv > cp[CP_FLOOR2] ? lv : cp[CP_FLOOR2];
    st[CS_LINEAR_VAR] = lv < cp[CP_LINEAR_MAX2] ? lv : cp[CP_LINEAR_MAX2];
    long learn;
    if (st[CS_ADAPT_N] < cp[CP_STEADY_AFTER])
        learn = 4; /* Learn.IF_CONSISTENT */
    else if (st[CS_LINEAR_VAR] <= cp[CP_STEADY2])
        learn = 0; /* ALL */
    else
        learn = 1; /* HORIZONTAL */
    const double rd[2] = {var, var};
    double e[4];
    long code;
    if (update_core(p, h, 2, y, rd, cp[CP_GATE], learn, cp[CP_CONSISTENT], q, keep_heading, b,
                    a, e)) {
        /* the next window's first half turns with the world (ekf._rotate) */
        const double w = e[0], x = e[1], yq = e[2], z = e[3];
        const double r0 = st[CS_RISE], r1 = st[CS_RISE + 1], r2 = st[CS_RISE + 2];
        st[CS_RISE] = (1 - 2 * (yq * yq + z * z)) * r0 + 2 * (x * yq - w * z) * r1 +
                      2 * (x * z + w * yq) * r2;
        st[CS_RISE + 1] = 2 * (x * yq + w * z) * r0 + (1 - 2 * (x * x + z * z)) * r1 +
                          2 * (yq * z - w * x) * r2;
        st[CS_RISE + 2] = 2 * (x * z - w * yq) * r0 + 2 * (yq * z + w * x) * r1 +
                          (1 - 2 * (x * x + yq * yq)) * r2;
        st[CS_G0_N] += 1.0;
        const double g0_gain = 1.0 / st[CS_G0_N] > cp[CP_G0_GAIN] ? 1.0 / st[CS_G0_N]
                                                                   : cp[CP_G0_GAIN];
        st[CS_G0] = g0 + g0_gain * (g - g0);
        st[CS_G_VAR] += cp[CP_WHITE_GAIN] * ((g - g0) * (g - g0) - st[CS_G_VAR]);
        st[CS_REJECTED_S] = st[CS_DRIFTED_S] = 0.0;
        code = 0;
    } else {
        st[CS_REJECTED_S] += t;
        const double claimed = yy2 / (2.0 * g0);
        const double sd = sqrt(cp[CP_ACCEL2] / tt + st[CS_G_VAR]);
        const double seen = g - g0;
        const int drifted = seen < cp[CP_DRIFT_SHARE] * claimed &&
                            claimed - seen > cp[CP_DRIFT_SIGMAS] * sd;
        st[CS_DRIFTED_S] = drifted ? st[CS_DRIFTED_S] + t : 0.0;
        code = 1;
        if (st[CS_DRIFTED_S] >= cp[CP_DRIFT_S] || st[CS_REJECTED_S] >= cp[CP_RECOVERY_S]) {
            for (int i = 0; i < 3; i++)
                st[CS_MEAN + i] = mean[i];
            st[CS_REJECTED_S] = st[CS_DRIFTED_S] = 0.0;
            code = 2;
        }
    }
    release_all(v, 11);
    return PyLong_FromLong(code);
}

/* --- the gyro-bias tracker's windows (calib.track, its NumPy twin) --- */

#define TW_BLOCKS 8 /* calib.track.BLOCKS */
/* the running window's state, in doubles: */
enum {
    TW_COUNT, TW_BAD, TW_NO_ACCEL, TW_G0, TW_A0 = TW_G0 + 3, TW_SG = TW_A0 + 3, TW_SGG = TW_SG + 3,
    TW_SA = TW_SGG + 3, TW_SAA = TW_SA + 3, TW_BG = TW_SAA + 3, TW_BA = TW_BG + 3 * TW_BLOCKS,
    TW_STATE = TW_BA + 3 * TW_BLOCKS
};
/* and a finished window's row: */
enum {
    TR_OK, TR_ACCEL, TR_GMEAN, TR_GVAR = TR_GMEAN + 3, TR_AMEAN = TR_GVAR + 3,
    TR_AVAR = TR_AMEAN + 3, TR_GRATIO = TR_AVAR + 3, TR_ARATIO, TR_ROW
};

/* One signal's mean, variance (ddof 1) and long-run ratio from shifted sums. */
static double tw_stats(const double *st, int shift, int s1, int s2, int blocks, long m,
                       double *mean, double *var) {
    double vsum = 0.0;
    for (int d = 0; d < 3; d++) {
        const double a = st[s1 + d], b = st[s2 + d];
        mean[d] = st[shift + d] + a / (double)m;
        var[d] = (b - a * a / (double)m) / (double)(m - 1);
        vsum += var[d];
    }
    if (m < 4 * TW_BLOCKS)
        return 1.0;
    const long b = m / TW_BLOCKS;
    double long_run = 0.0;
    for (int d = 0; d < 3; d++) {
        double bm[TW_BLOCKS], mm = 0.0;
        for (int k = 0; k < TW_BLOCKS; k++) {
            bm[k] = st[blocks + 3 * k + d] / (double)b;
            mm += bm[k];
        }
        mm /= TW_BLOCKS;
        double acc = 0.0;
        for (int k = 0; k < TW_BLOCKS; k++)
            acc += (bm[k] - mm) * (bm[k] - mm);
        long_run += acc / (TW_BLOCKS - 1);
    }
    return long_run * (double)b / (vsum > 1e-30 ? vsum : 1e-30);
}

/* track_windows(gyro, accel, m, state, out) -> windows
 *
 * Feeds a batch (n x 3 each; accel may be None) into the running window of `m` samples whose
 * sums `state` holds (TW_STATE doubles, zeros at first), and writes each window the batch
 * completes as a row of `out` (TR_ROW doubles each): whether it had no invalid value, whether
 * every sample had an accelerometer reading, each signal's mean and variance (ddof 1) per axis
 * and its long-run variance ratio (calib.track.long_run_ratio). Values are summed less the
 * window's first sample, so the variance of a signal far from zero keeps its digits. */
static PyObject *track_windows(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    (void)self;
    if (nargs != 5) {
        PyErr_SetString(PyExc_TypeError, "track_windows() takes 5 arguments");
        return NULL;
    }
    const long m = PyLong_AsLong(args[2]);
    if (PyErr_Occurred())
        return NULL;
    if (m < 2) {
        PyErr_SetString(PyExc_ValueError, "track_windows: windows of at least 2 samples");
        return NULL;
    }
    const int has_accel = args[1] != Py_None;
    Py_buffer gb, ab, sb, ob;
    if (!get_f64(args[0], &gb, "track_windows gyro"))
        return NULL;
    const Py_ssize_t n = gb.len / 24;
    if (has_accel && !get_f64(args[1], &ab, "track_windows accel")) {
        PyBuffer_Release(&gb);
        return NULL;
    }
    if (gb.len != n * 24 || (has_accel && ab.len != n * 24)) {
        PyBuffer_Release(&gb);
        if (has_accel)
            PyBuffer_Release(&ab);
        PyErr_SetString(PyExc_ValueError, "track_windows: gyro and accel of n x 3 each");
        return NULL;
    }
    if (!get_buffer(args[3], &sb, TW_STATE * 8, 1, "track_windows state")) {
        PyBuffer_Release(&gb);
        if (has_accel)
            PyBuffer_Release(&ab);
        return NULL;
    }
    if (!get_buffer(args[4], &ob, 0, 1, "track_windows out")) {
        PyBuffer_Release(&gb);
        PyBuffer_Release(&sb);
        if (has_accel)
            PyBuffer_Release(&ab);
        return NULL;
    }
    const Py_ssize_t cap = ob.len / (TR_ROW * 8);
    const double *g = gb.buf, *a = has_accel ? ab.buf : NULL;
    double *st = sb.buf, *out = ob.buf;
    const long b = m / TW_BLOCKS;
    Py_ssize_t rows = 0;
    int full = 0;
    for (Py_ssize_t i = 0; i < n; i++) {
        long c = (long)st[TW_COUNT];
        if (c == 0) {
            memset(st, 0, TW_STATE * sizeof(double));
            for (int d = 0; d < 3; d++) {
                st[TW_G0 + d] = g[3 * i + d];
                st[TW_A0 + d] = a != NULL ? a[3 * i + d] : 0.0;
            }
        }
        if (a == NULL)
            st[TW_NO_ACCEL] = 1.0;
        const int blk = (b > 0 && c < b * TW_BLOCKS) ? (int)(c / b) : -1;
        for (int d = 0; d < 3; d++) {
            const double x = g[3 * i + d];
            if (!isfinite(x))
                st[TW_BAD] += 1.0;
            const double dx = x - st[TW_G0 + d];
            st[TW_SG + d] += dx;
            st[TW_SGG + d] += dx * dx;
            if (blk >= 0)
                st[TW_BG + 3 * blk + d] += x - st[TW_G0 + d];
            if (a != NULL) {
                const double y = a[3 * i + d];
                if (!isfinite(y))
                    st[TW_BAD] += 1.0;
                const double dy = y - st[TW_A0 + d];
                st[TW_SA + d] += dy;
                st[TW_SAA + d] += dy * dy;
                if (blk >= 0)
                    st[TW_BA + 3 * blk + d] += dy;
            }
        }
        st[TW_COUNT] = (double)(++c);
        if (c < m)
            continue;
        if (rows >= cap) {
            full = 1;
            break;
        }
        double *r = out + TR_ROW * rows++;
        memset(r, 0, TR_ROW * sizeof(double));
        r[TR_OK] = st[TW_BAD] == 0.0;
        r[TR_ACCEL] = st[TW_NO_ACCEL] == 0.0;
        r[TR_GRATIO] = tw_stats(st, TW_G0, TW_SG, TW_SGG, TW_BG, m, r + TR_GMEAN, r + TR_GVAR);
        r[TR_ARATIO] = r[TR_ACCEL] != 0.0
                           ? tw_stats(st, TW_A0, TW_SA, TW_SAA, TW_BA, m, r + TR_AMEAN,
                                      r + TR_AVAR)
                           : 1.0;
        st[TW_COUNT] = 0.0;
    }
    PyBuffer_Release(&gb);
    PyBuffer_Release(&sb);
    PyBuffer_Release(&ob);
    if (has_accel)
        PyBuffer_Release(&ab);
    if (full) {
        PyErr_SetString(PyExc_ValueError, "track_windows: out holds too few rows");
        return NULL;
    }
    return PyLong_FromSsize_t(rows);
}

static PyMethodDef methods[] = {
    {"stamps", (PyCFunction)(void (*)(void))stamps, METH_FASTCALL,
     "Stamps on the fitted line, steered and rounded (SampleClock.update's tail)."},
    {"tick_steps", (PyCFunction)(void (*)(void))tick_steps, METH_FASTCALL,
     "(largest, sum) of a counter's steps modulo its wrap."},
    {"bracket", (PyCFunction)(void (*)(void))bracket, METH_FASTCALL,
     "Where times fall among another die's samples (the align stage)."},
    {"lerp", (PyCFunction)(void (*)(void))lerp, METH_FASTCALL,
     "One channel interpolated at bracketed times, and where it has no value."},
    {"pack", (PyCFunction)(void (*)(void))pack, METH_FASTCALL,
     "A wire batch's stamps, flags and float32 channels after its header."},
    {"orient_chunk", (PyCFunction)(void (*)(void))orient_chunk, METH_FASTCALL,
     "The orientation filter's integration of one chunk of gyro samples."},
    {"orient_sums", (PyCFunction)(void (*)(void))orient_sums, METH_FASTCALL,
     "An interval's rotated specific-force sums (orient.kalman)."},
    {"orient_propagate", (PyCFunction)(void (*)(void))orient_propagate, METH_FASTCALL,
     "The orientation covariance over an interval, in place (orient.kalman)."},
    {"orient_gravity_h", (PyCFunction)(void (*)(void))orient_gravity_h, METH_FASTCALL,
     "Gravity's measurement matrix and the trace of h P h^T (orient.kalman)."},
    {"orient_update", (PyCFunction)(void (*)(void))orient_update, METH_FASTCALL,
     "A gated, Schmidt-capable Kalman update of the orientation covariance (orient.kalman)."},
    {"track_windows", (PyCFunction)(void (*)(void))track_windows, METH_FASTCALL,
     "The gyro-bias tracker's windows: each one's means, variances and long-run ratios."},
    {"orient_correct", (PyCFunction)(void (*)(void))orient_correct, METH_FASTCALL,
     "One gravity correction of the orientation filter, in one call (orient.ekf)."},
    {"reaches", (PyCFunction)(void (*)(void))reaches, METH_FASTCALL,
     "Whether any int32 count is at or beyond +-full_scale."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_kernels", NULL, -1, methods};

PyMODINIT_FUNC PyInit__kernels(void) { return PyModule_Create(&module); }
