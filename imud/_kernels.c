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

/* A buffer of at least `need` bytes, writable or not; raises and returns 0 otherwise. */
static int get_buffer(PyObject *obj, Py_buffer *view, Py_ssize_t need, int writable,
                      const char *what) {
    if (PyObject_GetBuffer(obj, view, writable ? PyBUF_WRITABLE | PyBUF_C_CONTIGUOUS
                                               : PyBUF_C_CONTIGUOUS) < 0)
        return 0;
    if (view->len < need) {
        PyErr_Format(PyExc_ValueError, "%s: %zd bytes, need %zd", what, view->len, need);
        PyBuffer_Release(view);
        return 0;
    }
    return 1;
}

/* Whether a buffer holds native-order signed integers of `size` bytes: its format (after an
 * optional byte-order mark for this machine's order) is one of `codes` whose C type has that
 * size (NumPy exports int32 as "i" or "<i", int64 as "l" or "q"). */
static int is_native(const Py_buffer *v, Py_ssize_t size, const char *codes) {
    const char *f = v->format;
    if (v->itemsize != size || f == NULL)
        return 0;
    if ((f[0] == '<' && !PY_BIG_ENDIAN) || f[0] == '=' || f[0] == '@')
        f++;
    if (f[0] == 0 || f[1] != 0 || strchr(codes, f[0]) == NULL)
        return 0;
    switch (f[0]) {
    case 'i': return sizeof(int) == size;
    case 'l': return sizeof(long) == size;
    case 'q': return sizeof(long long) == size;
    default: return 0;
    }
}

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
        t[i] = (int64_t)rint(est);
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
        long long d = (v[i] - v[i - 1]) % mod;
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
 * Whether any int32 count in `data` is at or beyond +-full_scale: a sensor at its range's end
 * (the pipeline's saturation flag, whose per-sample work runs only when this says so). */
static PyObject *reaches(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    if (nargs != 2) {
        PyErr_SetString(PyExc_TypeError, "reaches() takes 2 arguments");
        return NULL;
    }
    double fs = PyFloat_AsDouble(args[1]);
    if (PyErr_Occurred())
        return NULL;
    Py_buffer in;
    if (PyObject_GetBuffer(args[0], &in, PyBUF_C_CONTIGUOUS | PyBUF_FORMAT) < 0)
        return NULL;
    if (!is_native(&in, 4, "il")) {
        PyBuffer_Release(&in);
        PyErr_SetString(PyExc_TypeError, "reaches: data must hold native int32 counts");
        return NULL;
    }
    Py_ssize_t n = in.len / 4;
    const int32_t *v = (const int32_t *)in.buf;
    int32_t lo = 0, hi = 0;
    for (Py_ssize_t i = 0; i < n; i++) {
        lo = v[i] < lo ? v[i] : lo;
        hi = v[i] > hi ? v[i] : hi;
    }
    PyBuffer_Release(&in);
    return PyBool_FromLong((double)hi >= fs || (double)lo <= -fs);
}

static PyMethodDef methods[] = {
    {"stamps", (PyCFunction)(void (*)(void))stamps, METH_FASTCALL,
     "Stamps on the fitted line, steered and rounded (SampleClock.update's tail)."},
    {"tick_steps", (PyCFunction)(void (*)(void))tick_steps, METH_FASTCALL,
     "(largest, sum) of a counter's steps modulo its wrap."},
    {"reaches", (PyCFunction)(void (*)(void))reaches, METH_FASTCALL,
     "Whether any int32 count is at or beyond +-full_scale."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_kernels", NULL, -1, methods};

PyMODINIT_FUNC PyInit__kernels(void) { return PyModule_Create(&module); }
