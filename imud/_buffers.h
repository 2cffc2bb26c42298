/* Buffer helpers shared by imud's compiled kernels (included, so each extension has its own
 * copy: they are a few lines, and the extensions stay one file each). */
#ifndef IMUD_BUFFERS_H
#define IMUD_BUFFERS_H

#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include <string.h>

/* A buffer of at least `need` bytes, writable or not; raises and returns 0 otherwise. */
static inline int get_buffer(PyObject *obj, Py_buffer *view, Py_ssize_t need, int writable,
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

/* A C-contiguous buffer of native float64s (a NumPy float64 array as the filter and pipeline
 * make them), read-only; raises ValueError (NumPy's, not contiguous) or TypeError (another
 * type) and returns 0 otherwise, so a caller can fall back to converting it. */
static inline int get_f64(PyObject *obj, Py_buffer *view, const char *what) {
    if (PyObject_GetBuffer(obj, view, PyBUF_C_CONTIGUOUS | PyBUF_FORMAT) < 0)
        return 0;
    const char *f = view->format;
    if (f != NULL && ((f[0] == '<' && !PY_BIG_ENDIAN) || f[0] == '=' || f[0] == '@'))
        f++;
    if (view->itemsize != 8 || f == NULL || f[0] != 'd' || f[1] != 0) {
        PyErr_Format(PyExc_TypeError, "%s: float64 values needed", what);
        PyBuffer_Release(view);
        return 0;
    }
    return 1;
}

/* Whether a buffer holds native-order signed integers of `size` bytes: its format (after an
 * optional byte-order mark for this machine's order) is one of `codes` whose C type has that
 * size (NumPy exports int32 as "i" or "<i", int64 as "l" or "q"). */
static inline int is_native(const Py_buffer *v, Py_ssize_t size, const char *codes) {
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

#endif
