/* drivers._bitpack: the DBC codec's per-message fast path, compiled.
 *
 * Packer(length, signals) packs the signals of one classic-CAN message (at most 8 bytes, little-endian integer
 * signals) from positional values and unpacks a payload into a tuple. signals is a sequence of
 *     (start, bits, signed, kind, scale, offset, lo, hi, raw_lo, raw_hi)
 * in the order the caller passes the values; kind 0 = identity (physical is the raw integer), 1 = integer scale and
 * offset (physical stays an int), 2 = anything else (physical is a float). drivers.dbc builds them from the DBC.
 *
 * It is the generated Python of drivers.dbc._compile_message in C, with the same results to the bit:
 *   - pack takes exactly a float, an int or a bool per signal within [lo, hi] (NaN is not), rounds
 *     (v - offset) / scale half to even (nearbyint in the default rounding mode is Python's round), checks the raw
 *     range, and masks and shifts it into the word. Anything else returns None, and the caller's general path
 *     decides (and raises the error that names the field): an int beyond 2**52, a numpy scalar, an enum name.
 *   - unpack computes raw * scale + offset as Python does (an int for kinds 0 and 1, a float for kind 2).
 * The float arithmetic is one multiply or divide and one add or subtract per signal; setup.py builds this file with
 * -ffp-contract=off so the compiler cannot fuse them into an FMA (which would change the last bit).
 * tests/drivers/test_dbc_native.py compares the two implementations on random values and payloads.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <math.h>
#include <stdint.h>

#define MAX_SIGNALS 64
#define EXACT_INT ((int64_t)1 << 52) /* ints up to this convert to double and subtract exactly */

typedef struct {
    int start, kind;
    uint64_t mask, sign_bit;
    double scale, offset, lo, hi;
    int64_t iscale, ioffset, raw_lo, raw_hi;
} Signal;

typedef struct {
    PyObject_HEAD
    Py_ssize_t n;
    int length;
    Signal sig[MAX_SIGNALS];
} Packer;

static int Packer_init(Packer *self, PyObject *args, PyObject *kwds)
{
    int length;
    PyObject *signals;
    if (kwds != NULL && PyDict_GET_SIZE(kwds)) {
        PyErr_SetString(PyExc_TypeError, "Packer(length, signals) takes no keyword arguments");
        return -1;
    }
    if (!PyArg_ParseTuple(args, "iO:Packer", &length, &signals))
        return -1;
    if (length < 1 || length > 8) {
        PyErr_Format(PyExc_ValueError, "Packer: length = %d bytes; 1 to 8 (classic CAN)", length);
        return -1;
    }
    PyObject *seq = PySequence_Fast(signals, "Packer: signals must be a sequence of tuples");
    if (seq == NULL)
        return -1;
    Py_ssize_t n = PySequence_Fast_GET_SIZE(seq);
    if (n > MAX_SIGNALS) {
        Py_DECREF(seq);
        PyErr_SetString(PyExc_ValueError, "Packer: more than 64 signals");
        return -1;
    }
    for (Py_ssize_t i = 0; i < n; i++) {
        Signal *s = &self->sig[i];
        int bits, is_signed;
        long long raw_lo, raw_hi;
        if (!PyArg_ParseTuple(PySequence_Fast_GET_ITEM(seq, i), "iipiddddLL:Packer signal", &s->start, &bits,
                              &is_signed, &s->kind, &s->scale, &s->offset, &s->lo, &s->hi, &raw_lo, &raw_hi)) {
            Py_DECREF(seq);
            return -1;
        }
        if (bits < 1 || bits > 52 || s->start < 0 || s->start + bits > 8 * length || s->kind < 0 || s->kind > 2) {
            Py_DECREF(seq);
            PyErr_Format(PyExc_ValueError, "Packer: signal %zd (start %d, %d bits, kind %d) is not supported", i,
                         s->start, bits, s->kind);
            return -1;
        }
        s->mask = ((uint64_t)1 << bits) - 1;
        s->sign_bit = is_signed ? (uint64_t)1 << (bits - 1) : 0;
        s->iscale = (int64_t)s->scale;
        s->ioffset = (int64_t)s->offset;
        s->raw_lo = raw_lo;
        s->raw_hi = raw_hi;
        if (s->kind == 1 && (s->iscale != s->scale || s->ioffset != s->offset || fabs(s->scale) > 1024.0
                             || fabs(s->offset) > (double)EXACT_INT)) {
            Py_DECREF(seq);
            PyErr_Format(PyExc_ValueError, "Packer: signal %zd has an integer scale or offset out of reach", i);
            return -1;
        }
    }
    Py_DECREF(seq);
    self->n = n;
    self->length = length;
    return 0;
}

static PyObject *Packer_pack(Packer *self, PyObject *const *args, Py_ssize_t nargs)
{
    if (nargs != self->n) {
        PyErr_Format(PyExc_TypeError, "pack() takes %zd values; got %zd", self->n, nargs);
        return NULL;
    }
    uint64_t word = 0;
    for (Py_ssize_t i = 0; i < nargs; i++) {
        const Signal *s = &self->sig[i];
        PyObject *v = args[i];
        double x;
        int64_t iv = 0;
        int is_int;
        if (PyFloat_CheckExact(v)) {
            x = PyFloat_AS_DOUBLE(v);
            is_int = 0;
        } else if (PyLong_CheckExact(v) || PyBool_Check(v)) {
            int overflow;
            long long ll = PyLong_AsLongLongAndOverflow(v, &overflow);
            if (overflow || ll > EXACT_INT || ll < -EXACT_INT)
                Py_RETURN_NONE;
            iv = ll;
            x = (double)iv;
            is_int = 1;
        } else {
            Py_RETURN_NONE;
        }
        if (!(s->lo <= x && x <= s->hi))
            Py_RETURN_NONE;
        int64_t raw;
        if (s->kind == 0) {
            raw = is_int ? iv : (int64_t)nearbyint(x);
        } else {
            double q;
            if (s->kind == 1 && is_int)
                q = (double)(iv - s->ioffset) / (double)s->iscale;
            else
                q = (x - s->offset) / s->scale;
            q = nearbyint(q);
            if (!(fabs(q) < 9.0e18))
                Py_RETURN_NONE;
            raw = (int64_t)q;
        }
        if (raw < s->raw_lo || raw > s->raw_hi)
            Py_RETURN_NONE;
        word |= ((uint64_t)raw & s->mask) << s->start;
    }
    unsigned char out[8];
    for (int b = 0; b < self->length; b++)
        out[b] = (unsigned char)(word >> (8 * b));
    return PyBytes_FromStringAndSize((const char *)out, self->length);
}

static PyObject *Packer_unpack(Packer *self, PyObject *data)
{
    Py_buffer view;
    if (PyObject_GetBuffer(data, &view, PyBUF_SIMPLE) < 0)
        return NULL;
    if (view.len != self->length) {
        PyBuffer_Release(&view);
        PyErr_Format(PyExc_ValueError, "unpack() takes %d bytes; got %zd", self->length, view.len);
        return NULL;
    }
    uint64_t word = 0;
    const unsigned char *p = view.buf;
    for (int b = 0; b < self->length; b++)
        word |= (uint64_t)p[b] << (8 * b);
    PyBuffer_Release(&view);
    PyObject *out = PyTuple_New(self->n);
    if (out == NULL)
        return NULL;
    for (Py_ssize_t i = 0; i < self->n; i++) {
        const Signal *s = &self->sig[i];
        uint64_t u = (word >> s->start) & s->mask;
        int64_t r = s->sign_bit ? (int64_t)(u ^ s->sign_bit) - (int64_t)s->sign_bit : (int64_t)u;
        PyObject *value;
        if (s->kind == 0)
            value = PyLong_FromLongLong(r);
        else if (s->kind == 1)
            value = PyLong_FromLongLong(r * s->iscale + s->ioffset);
        else
            value = PyFloat_FromDouble((double)r * s->scale + s->offset);
        if (value == NULL) {
            Py_DECREF(out);
            return NULL;
        }
        PyTuple_SET_ITEM(out, i, value);
    }
    return out;
}

static PyMethodDef Packer_methods[] = {
    {"pack", (PyCFunction)(void (*)(void))Packer_pack, METH_FASTCALL,
     "pack(*values) -> payload bytes, or None where the general path must decide"},
    {"unpack", (PyCFunction)Packer_unpack, METH_O, "unpack(payload) -> tuple of physical values"},
    {NULL, NULL, 0, NULL},
};

static PyType_Slot Packer_slots[] = {
    {Py_tp_init, Packer_init},
    {Py_tp_new, PyType_GenericNew},
    {Py_tp_methods, Packer_methods},
    {Py_tp_doc, "Packer(length, signals): one CAN message's signals packed from and unpacked to positional values."},
    {0, NULL},
};

static PyType_Spec Packer_spec = {"drivers._bitpack.Packer", sizeof(Packer), 0, Py_TPFLAGS_DEFAULT, Packer_slots};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "drivers._bitpack", "The DBC codec's fast path, compiled (see drivers.dbc).", -1, NULL,
};

PyMODINIT_FUNC PyInit__bitpack(void)
{
    PyObject *m = PyModule_Create(&module);
    if (m == NULL)
        return NULL;
    PyObject *type = PyType_FromSpec(&Packer_spec);
    if (type == NULL || PyModule_AddObject(m, "Packer", type) < 0) {
        Py_XDECREF(type);
        Py_DECREF(m);
        return NULL;
    }
    return m;
}
