/* imud.chips.icm42688p._fifo: FIFO packets 3 and 4 to counts in one pass.
 *
 * The driver's NumPy decode (driver.decode_packets, the reference) takes a dozen NumPy calls
 * a read, and finding the breaks in the packets' timestamps four more: about 140 us a read of
 * 64 packets paced at 8 kHz, a sixth of imud's own cost on this chip. This does both in one call.
 * Results are the same to the bit (tests/test_compiled.py).
 *
 * Packet layouts (big-endian; docs/chips/icm42688p.md, registers.py):
 *   3 (16 bytes): header, accel x y z int16, gyro x y z int16, temperature int8, timestamp u16
 *   4 (20 bytes): header, accel int16 x3, gyro int16 x3, temperature int16, timestamp u16,
 *                 then three bytes of 20-bit extensions: accel's in the high nibbles, gyro's in
 *                 the low ones
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include <stdint.h>

#include "_buffers.h"

/* registers.Header; tests/test_compiled.py checks them against it */
#define HDR_EMPTY 0x80
#define HDR_ACCEL 0x40
#define HDR_GYRO 0x20
#define HDR_20 0x10
#define INVALID_16 (-32768)
#define INVALID_20 (-(1 << 19))
#define INVALID_TEMP_8 (-128)
#define TIMESTAMP_MODULO 65536

static inline int32_t be16(const uint8_t *p) { return (int16_t)(uint16_t)((p[0] << 8) | p[1]); }

/* decode(data, hires, break_over, accel, gyro, temp, ts, bad) -> (n, clean, breaks)
 *
 * data: whole packets (a trailing part is ignored). Outputs, each sized for every whole packet
 * in data: accel and gyro int32 (packets x 3), temp float64 (degC), ts int64 (the timestamp
 * field), bad bool (3 x packets: accel, gyro, temperature invalid). Decoding stops at the
 * first 'FIFO empty' header: n packets decoded. clean: n > 0 and no value invalid (the masks
 * all False). breaks: the indices after which the timestamps step more than break_over ticks
 * (0: not looked for), where the packets stop being consecutive samples. */
static PyObject *decode(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    if (nargs != 8) {
        PyErr_SetString(PyExc_TypeError, "decode() takes 8 arguments");
        return NULL;
    }
    int hires = PyObject_IsTrue(args[1]);
    double break_over = PyFloat_AsDouble(args[2]);
    if (hires < 0 || PyErr_Occurred())
        return NULL;
    Py_buffer d, a, g, t, s, b;
    if (PyObject_GetBuffer(args[0], &d, PyBUF_C_CONTIGUOUS) < 0)
        return NULL;
    const Py_ssize_t stride = hires ? 20 : 16;
    const Py_ssize_t cap = d.len / stride;
    int got = 0;
    if (get_buffer(args[3], &a, cap * 12, 1, "accel")) {
        got = 1;
        if (get_buffer(args[4], &g, cap * 12, 1, "gyro")) {
            got = 2;
            if (get_buffer(args[5], &t, cap * 8, 1, "temp")) {
                got = 3;
                if (get_buffer(args[6], &s, cap * 8, 1, "ts")) {
                    got = 4;
                    if (get_buffer(args[7], &b, cap * 3, 1, "bad"))
                        got = 5;
                }
            }
        }
    }
    if (got < 5) {
        if (got > 3) PyBuffer_Release(&s);
        if (got > 2) PyBuffer_Release(&t);
        if (got > 1) PyBuffer_Release(&g);
        if (got > 0) PyBuffer_Release(&a);
        PyBuffer_Release(&d);
        return NULL;
    }
    const uint8_t *p = (const uint8_t *)d.buf;
    int32_t *acc = (int32_t *)a.buf, *gyr = (int32_t *)g.buf;
    double *temp = (double *)t.buf;
    int64_t *ts = (int64_t *)s.buf;
    uint8_t *abad = (uint8_t *)b.buf, *gbad = abad + cap, *tbad = abad + 2 * cap;
    const int32_t marker = hires ? INVALID_20 : INVALID_16;
    const int need = HDR_ACCEL | HDR_GYRO | (hires ? HDR_20 : 0);
    int hdr_all = 0xFF, any_tbad = 0;
    int32_t amin = INT32_MAX, gmin = INT32_MAX;
    Py_ssize_t n = 0;
    for (; n < cap; n++, p += stride) {
        const int hdr = p[0];
        if (hdr & HDR_EMPTY)
            break;
        int32_t av[3], gv[3];
        for (int i = 0; i < 3; i++) {
            av[i] = be16(p + 1 + 2 * i);
            gv[i] = be16(p + 7 + 2 * i);
        }
        int temp_bad;
        if (hires) {
            const int32_t raw = be16(p + 13);
            for (int i = 0; i < 3; i++) {
                /* (x << 4) as NumPy does it on int32: two's complement, no overflow trap */
                av[i] = (int32_t)((uint32_t)av[i] << 4) | (p[17 + i] >> 4);
                gv[i] = (int32_t)((uint32_t)gv[i] << 4) | (p[17 + i] & 0x0F);
            }
            temp[n] = (double)raw / 132.48 + 25.0;
            temp_bad = raw == INVALID_16;
            ts[n] = (p[15] << 8) | p[16];
        } else {
            const int32_t raw = (int8_t)p[13];
            temp[n] = (double)raw / 2.07 + 25.0;
            temp_bad = raw == INVALID_TEMP_8;
            ts[n] = (p[14] << 8) | p[15];
        }
        const int no_20 = hires && !(hdr & HDR_20);
        for (int i = 0; i < 3; i++) {
            acc[3 * n + i] = av[i];
            gyr[3 * n + i] = gv[i];
            amin = av[i] < amin ? av[i] : amin;
            gmin = gv[i] < gmin ? gv[i] : gmin;
        }
        abad[n] = !(hdr & HDR_ACCEL) ||
                  (av[0] == marker && av[1] == marker && av[2] == marker) || no_20;
        gbad[n] = !(hdr & HDR_GYRO) ||
                  (gv[0] == marker && gv[1] == marker && gv[2] == marker) || no_20;
        tbad[n] = (uint8_t)temp_bad;
        hdr_all &= hdr;
        any_tbad |= temp_bad;
    }
    const int clean = n > 0 && (hdr_all & need) == need && amin > marker && gmin > marker &&
                      !any_tbad;
    PyObject *breaks = PyList_New(0);
    if (breaks != NULL && break_over > 0) {
        for (Py_ssize_t i = 1; i < n; i++) {
            const int64_t step = ((ts[i] - ts[i - 1]) % TIMESTAMP_MODULO + TIMESTAMP_MODULO) %
                                 TIMESTAMP_MODULO;
            if ((double)step > break_over) {
                PyObject *at = PyLong_FromSsize_t(i);
                if (at == NULL || PyList_Append(breaks, at) < 0) {
                    Py_XDECREF(at);
                    Py_CLEAR(breaks);
                    break;
                }
                Py_DECREF(at);
            }
        }
    }
    PyBuffer_Release(&b);
    PyBuffer_Release(&s);
    PyBuffer_Release(&t);
    PyBuffer_Release(&g);
    PyBuffer_Release(&a);
    PyBuffer_Release(&d);
    if (breaks == NULL)
        return NULL;
    return Py_BuildValue("(nON)", n, clean ? Py_True : Py_False, breaks);
}

static PyMethodDef methods[] = {
    {"decode", (PyCFunction)(void (*)(void))decode, METH_FASTCALL,
     "FIFO packets to counts, up to the first 'FIFO empty' header, and their breaks."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_fifo", NULL, -1, methods};

PyMODINIT_FUNC PyInit__fifo(void) {
    PyObject *m = PyModule_Create(&module);
    if (m == NULL)
        return NULL;
    if (PyModule_AddIntConstant(m, "HDR_EMPTY", HDR_EMPTY) < 0 ||
        PyModule_AddIntConstant(m, "HDR_ACCEL", HDR_ACCEL) < 0 ||
        PyModule_AddIntConstant(m, "HDR_GYRO", HDR_GYRO) < 0 ||
        PyModule_AddIntConstant(m, "HDR_20", HDR_20) < 0 ||
        PyModule_AddIntConstant(m, "INVALID_16", INVALID_16) < 0 ||
        PyModule_AddIntConstant(m, "INVALID_20", INVALID_20) < 0 ||
        PyModule_AddIntConstant(m, "INVALID_TEMP_8", INVALID_TEMP_8) < 0 ||
        PyModule_AddIntConstant(m, "TIMESTAMP_MODULO", TIMESTAMP_MODULO) < 0) {
        Py_DECREF(m);
        return NULL;
    }
    return m;
}
