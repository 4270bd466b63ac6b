/* sim._native: the default scenario's attitude step, compiled.
 *
 * rk4_magnetic_gg(q, w, h, I, Ii, dipole_B, fields_N, positions_N, mu) is sim.truth.rk4_magnetic_gg in C: the same
 * IEEE-754 double operations in the same order (C evaluates a + b + c as (a + b) + c, as Python does), so the
 * result is the same to the bit. That only holds when the compiler neither fuses a multiply and an add into one
 * FMA nor reorders sums: setup.py builds this file with -ffp-contract=off and never with -ffast-math, and
 * tests/sim/test_native.py compares the two implementations bit for bit on random states.
 *
 * Why C: the step is about 40 floating-point lines run four times per tick; in Python each operation is a boxed
 * float, so the step cost ~7 us, most of a physics tick. Python's sqrt and isfinite are the C library's, so
 * nothing else differs. The build is optional (setup.py): without a C compiler the stand runs the Python step.
 *
 * Returns ((q0, q1, q2, q3), (w0, w1, w2)) normalised, or None when the new state is not finite (the caller
 * raises the stand's own error, sim.rigid_body.non_finite_state).
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <math.h>

/* n floats from a tuple or a list (ints accepted, as Python's arithmetic accepts them). */
static int read_floats(PyObject *seq, double *out, Py_ssize_t n, const char *what)
{
    PyObject **items;
    if (PyTuple_Check(seq)) {
        if (PyTuple_GET_SIZE(seq) != n)
            goto bad;
        items = &PyTuple_GET_ITEM(seq, 0);
    } else if (PyList_Check(seq)) {
        if (PyList_GET_SIZE(seq) != n)
            goto bad;
        items = &PyList_GET_ITEM(seq, 0);
    } else {
        goto bad;
    }
    for (Py_ssize_t i = 0; i < n; i++) {
        PyObject *x = items[i];
        out[i] = PyFloat_CheckExact(x) ? PyFloat_AS_DOUBLE(x) : PyFloat_AsDouble(x);
        if (out[i] == -1.0 && PyErr_Occurred())
            return -1;
    }
    return 0;
bad:
    PyErr_Format(PyExc_TypeError, "rk4_magnetic_gg: %s must be a tuple or list of %zd floats", what, n);
    return -1;
}

static PyObject *rk4_magnetic_gg(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    double q[4], w[3], I[9], Ii[9], m[3], f[9], p[9], h, mu;
    if (nargs != 9) {
        PyErr_SetString(PyExc_TypeError,
                        "rk4_magnetic_gg(q, w, h, I, Ii, dipole_B, fields_N, positions_N, mu) takes 9 arguments");
        return NULL;
    }
    if (read_floats(args[0], q, 4, "q") || read_floats(args[1], w, 3, "w") || read_floats(args[3], I, 9, "I")
        || read_floats(args[4], Ii, 9, "Ii") || read_floats(args[5], m, 3, "dipole_B")
        || read_floats(args[6], f, 9, "fields_N") || read_floats(args[7], p, 9, "positions_N"))
        return NULL;
    h = PyFloat_AsDouble(args[2]);
    if (h == -1.0 && PyErr_Occurred())
        return NULL;
    mu = PyFloat_AsDouble(args[8]);
    if (mu == -1.0 && PyErr_Occurred())
        return NULL;

    const double i00 = I[0], i01 = I[1], i02 = I[2], i10 = I[3], i11 = I[4], i12 = I[5], i20 = I[6], i21 = I[7],
                 i22 = I[8];
    const double j00 = Ii[0], j01 = Ii[1], j02 = Ii[2], j10 = Ii[3], j11 = Ii[4], j12 = Ii[5], j20 = Ii[6],
                 j21 = Ii[7], j22 = Ii[8];
    const double mx = m[0], my = m[1], mz = m[2];
    const double q0 = q[0], q1 = q[1], q2 = q[2], q3 = q[3], w0 = w[0], w1 = w[1], w2 = w[2];
    const double h2 = 0.5 * h, gm3 = 3.0 * mu;
    double k[4][7];
    double qw = q0, qx = q1, qy = q2, qz = q3, wx = w0, wy = w1, wz = w2;
    for (int stage = 0; stage < 4; stage++) {
        const int o = stage == 0 ? 0 : (stage < 3 ? 3 : 6);
        const double fx = f[o], fy = f[o + 1], fz = f[o + 2];
        const double vx = p[o], vy = p[o + 1], vz = p[o + 2];
        /* the field and the position rotated into body axes */
        double cx = qy * fz - qz * fy;
        double cy = qz * fx - qx * fz;
        double cz = qx * fy - qy * fx;
        const double bx = fx - 2.0 * (qw * cx - (qy * cz - qz * cy));
        const double by = fy - 2.0 * (qw * cy - (qz * cx - qx * cz));
        const double bz = fz - 2.0 * (qw * cz - (qx * cy - qy * cx));
        cx = qy * vz - qz * vy;
        cy = qz * vx - qx * vz;
        cz = qx * vy - qy * vx;
        const double rx = vx - 2.0 * (qw * cx - (qy * cz - qz * cy));
        const double ry = vy - 2.0 * (qw * cy - (qz * cx - qx * cz));
        const double rz = vz - 2.0 * (qw * cz - (qx * cy - qy * cx));
        /* magnetic (m x b) and gravity-gradient (3 mu / r^5 r x I r) torques */
        const double ix = i00 * rx + i01 * ry + i02 * rz;
        const double iy = i10 * rx + i11 * ry + i12 * rz;
        const double iz = i20 * rx + i21 * ry + i22 * rz;
        const double r2 = rx * rx + ry * ry + rz * rz;
        const double c = gm3 / (r2 * r2 * sqrt(r2));
        const double tx = (my * bz - mz * by) + c * (ry * iz - rz * iy);
        const double ty = (mz * bx - mx * bz) + c * (rz * ix - rx * iz);
        const double tz = (mx * by - my * bx) + c * (rx * iy - ry * ix);
        /* Euler's equations and the quaternion kinematics */
        const double hx = i00 * wx + i01 * wy + i02 * wz;
        const double hy = i10 * wx + i11 * wy + i12 * wz;
        const double hz = i20 * wx + i21 * wy + i22 * wz;
        const double ex = tx - (wy * hz - wz * hy);
        const double ey = ty - (wz * hx - wx * hz);
        const double ez = tz - (wx * hy - wy * hx);
        double *d = k[stage];
        d[4] = j00 * ex + j01 * ey + j02 * ez;
        d[5] = j10 * ex + j11 * ey + j12 * ez;
        d[6] = j20 * ex + j21 * ey + j22 * ez;
        d[0] = 0.5 * (-qx * wx - qy * wy - qz * wz);
        d[1] = 0.5 * (qw * wx + qy * wz - qz * wy);
        d[2] = 0.5 * (qw * wy - qx * wz + qz * wx);
        d[3] = 0.5 * (qw * wz + qx * wy - qy * wx);
        const double s = stage == 2 ? h : h2;
        qw = q0 + s * d[0];
        qx = q1 + s * d[1];
        qy = q2 + s * d[2];
        qz = q3 + s * d[3];
        wx = w0 + s * d[4];
        wy = w1 + s * d[5];
        wz = w2 + s * d[6];
    }
    const double h6 = h / 6.0;
    double n[7];
    const double start[7] = {q0, q1, q2, q3, w0, w1, w2};
    for (int i = 0; i < 7; i++)
        n[i] = start[i] + h6 * (k[0][i] + 2.0 * (k[1][i] + k[2][i]) + k[3][i]);
    const double norm = sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2] + n[3] * n[3]);
    if (!(isfinite(norm) && isfinite(n[4]) && isfinite(n[5]) && isfinite(n[6])))
        Py_RETURN_NONE;
    return Py_BuildValue("((dddd)(ddd))", n[0] / norm, n[1] / norm, n[2] / norm, n[3] / norm, n[4], n[5], n[6]);
}

static PyMethodDef methods[] = {
    {"rk4_magnetic_gg", (PyCFunction)(void (*)(void))rk4_magnetic_gg, METH_FASTCALL,
     "One RK4 step under magnetic and gravity-gradient torque; sim.truth.rk4_magnetic_gg to the bit."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "sim._native", "Compiled hot paths of sim (each has a Python original it equals).", -1,
    methods,
};

PyMODINIT_FUNC PyInit__native(void) { return PyModule_Create(&module); }
