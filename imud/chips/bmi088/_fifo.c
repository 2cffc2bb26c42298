/* imud.chips.bmi088._fifo: the accel die's framed FIFO walked in one pass.
 *
 * The NumPy walk (decode.decode_accel_fifo, the reference) takes a dozen NumPy calls for each
 * run of data frames and more for each control frame: about 70 us a read at the quick start's
 * 1.6 kHz, a sixth of imud's own cost on this chip. Same results (tests/test_compiled.py).
 *
 * Frames (docs/chips/bmi088.md, registers.py): a header byte matched on header & 0xFC; an
 * accel frame is the header and X, Y, Z little-endian int16 (7 bytes); skip, input-config and
 * sample-drop frames are 2 bytes (a skip frame's second byte counts the frames skipped); a
 * sensortime frame is 4 (a 24-bit little-endian time); 0x80 marks a read past the last frame.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include <stdint.h>

#include "_buffers.h"

/* registers.AccFifoHeader and ACC_FIFO_FRAME_BYTES; tests/test_compiled.py checks them */
#define HEADER_MASK 0xFC
#define HDR_ACCEL 0x84
#define HDR_SKIP 0x40
#define HDR_SENSORTIME 0x44
#define HDR_INPUT_CONFIG 0x48
#define HDR_SAMPLE_DROP 0x50
#define HDR_OVER_READ 0x80
#define ACCEL_FRAME 7

static Py_ssize_t control_size(int hdr) {
    switch (hdr) {
    case HDR_SKIP: case HDR_INPUT_CONFIG: case HDR_SAMPLE_DROP: return 2;
    case HDR_SENSORTIME: return 4;
    default: return 0;
    }
}

/* decode_accel(data, accel) -> (n, skipped, sensortime, over_read, corrupt_at)
 *
 * accel: int32, room for len(data) // 7 frames of 3 axes; the first n rows are the accel
 * frames in order. skipped: (accel frames before it, count) per skip frame. sensortime: the
 * last sensortime frame's value, or None. over_read: the walk reached the over-read marker.
 * corrupt_at: the byte offset of an unknown header (the walk stops there), or None. A frame
 * cut off by the read's end ends the walk. */
static PyObject *decode_accel(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    (void)self;
    if (nargs != 2) {
        PyErr_SetString(PyExc_TypeError, "decode_accel() takes 2 arguments");
        return NULL;
    }
    Py_buffer d, a;
    if (PyObject_GetBuffer(args[0], &d, PyBUF_C_CONTIGUOUS) < 0)
        return NULL;
    const Py_ssize_t len = d.len, cap = len / ACCEL_FRAME;
    if (!get_buffer(args[1], &a, cap * 12, 1, "accel")) {
        PyBuffer_Release(&d);
        return NULL;
    }
    const uint8_t *buf = (const uint8_t *)d.buf;
    int32_t *acc = (int32_t *)a.buf;
    PyObject *skipped = PyList_New(0);
    long sensortime = -1;
    int over_read = 0;
    Py_ssize_t corrupt_at = -1, n = 0, pos = 0;
    while (skipped != NULL && pos < len) {
        const int hdr = buf[pos] & HEADER_MASK;
        if (hdr == HDR_ACCEL) {
            if (pos + ACCEL_FRAME > len)
                break; /* cut short by the read's end */
            const uint8_t *f = buf + pos + 1;
            for (int i = 0; i < 3; i++)
                acc[3 * n + i] = (int16_t)(uint16_t)(f[2 * i] | (f[2 * i + 1] << 8));
            n++;
            pos += ACCEL_FRAME;
            continue;
        }
        if (hdr == HDR_OVER_READ) {
            over_read = 1;
            break;
        }
        const Py_ssize_t size = control_size(hdr);
        if (size == 0) {
            corrupt_at = pos;
            break;
        }
        if (pos + size > len)
            break; /* a control frame cut off by the read length */
        if (hdr == HDR_SKIP) {
            PyObject *item = Py_BuildValue("(ni)", n, (int)buf[pos + 1]);
            if (item == NULL || PyList_Append(skipped, item) < 0)
                Py_CLEAR(skipped);
            Py_XDECREF(item);
        } else if (hdr == HDR_SENSORTIME) {
            sensortime = buf[pos + 1] | (buf[pos + 2] << 8) | ((long)buf[pos + 3] << 16);
        }
        pos += size;
    }
    PyBuffer_Release(&a);
    PyBuffer_Release(&d);
    if (skipped == NULL)
        return NULL;
    PyObject *st = sensortime < 0 ? Py_NewRef(Py_None) : PyLong_FromLong(sensortime);
    PyObject *at = corrupt_at < 0 ? Py_NewRef(Py_None) : PyLong_FromSsize_t(corrupt_at);
    return Py_BuildValue("(nNNON)", n, skipped, st, over_read ? Py_True : Py_False, at);
}

static PyMethodDef methods[] = {
    {"decode_accel", (PyCFunction)(void (*)(void))decode_accel, METH_FASTCALL,
     "The accel FIFO's frames: accel counts, skip and sensortime frames, where it ended."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_fifo", NULL, -1, methods};

PyMODINIT_FUNC PyInit__fifo(void) {
    PyObject *m = PyModule_Create(&module);
    if (m == NULL)
        return NULL;
    if (PyModule_AddIntConstant(m, "HEADER_MASK", HEADER_MASK) < 0 ||
        PyModule_AddIntConstant(m, "HDR_ACCEL", HDR_ACCEL) < 0 ||
        PyModule_AddIntConstant(m, "HDR_SKIP", HDR_SKIP) < 0 ||
        PyModule_AddIntConstant(m, "HDR_SENSORTIME", HDR_SENSORTIME) < 0 ||
        PyModule_AddIntConstant(m, "HDR_INPUT_CONFIG", HDR_INPUT_CONFIG) < 0 ||
        PyModule_AddIntConstant(m, "HDR_SAMPLE_DROP", HDR_SAMPLE_DROP) < 0 ||
        PyModule_AddIntConstant(m, "HDR_OVER_READ", HDR_OVER_READ) < 0 ||
        PyModule_AddIntConstant(m, "ACCEL_FRAME", ACCEL_FRAME) < 0) {
        Py_DECREF(m);
        return NULL;
    }
    return m;
}
