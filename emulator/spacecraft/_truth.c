/* The truth's RK4 step in C (emulator.spacecraft.dynamics.Spacecraft.step): the same operations in the same order
 * as the Python form of Spacecraft.derivative (Eq. 4.10, 4.16, 4.55-4.56), _tau_ext (Eq. 4.69-4.75, 4.71, 4.73),
 * Wheels.limit, Wheels.jitter, TiltedDipoleField.field_floats, CircularOrbit.position, scenario.GridOrbit and
 * SurfaceTorques; built without floating-point contraction, so it agrees with the Python form to rounding.
 * An orbit, field or disturbance of another kind is called back in Python (``Kernel``'s *_fn arguments). */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <math.h>

#define API 1
#define NW 4

enum { ORB_NONE, ORB_CIRCULAR, ORB_GRID, ORB_PY };
enum { FLD_NONE, FLD_DIPOLE, FLD_PY };
enum { DST_NONE, DST_SURFACE, DST_PY };

typedef struct {
    PyObject_HEAD
    double J[9], Ji[9], C[12], CJ[12], jrw[NW];      /* 3 x 3 and 3 x 4 row by row */
    double fv, fc, fs, tmax, wmax, mu;               /* friction, limits, mu (m^3/s^2) */
    int gg, orbit, field, dist, jitter;
    double oa, on, ou0, op[3], ow[3];                /* CircularOrbit */
    double gt0, grate;                               /* GridOrbit */
    Py_buffer grid, force;                           /* GridOrbit.r (n, 3), SurfaceTorques.force_i (n, 3) */
    int has_grid, has_force;
    double gmst0, fm[3], r_earth, omega_e;           /* TiltedDipoleField */
    double st0, cp[3];                               /* SurfaceTorques */
    double g1[12], g2[12], r[12], us, ud;            /* jitter */
    PyObject *orbit_fn, *field_fn, *dist_fn;
} Kernel;

typedef struct { double r[3], b[3], f[3]; } Env;     /* what depends on t alone */

static int doubles(PyObject *v, const char *what, double *dst, Py_ssize_t n)
{
    PyObject *s = PySequence_Fast(v, what);
    if (s == NULL)
        return -1;
    if (PySequence_Fast_GET_SIZE(s) != n) {
        Py_DECREF(s);
        PyErr_Format(PyExc_ValueError, "%s must hold %zd numbers", what, n);
        return -1;
    }
    for (Py_ssize_t i = 0; i < n; i++)
        dst[i] = PyFloat_AsDouble(PySequence_Fast_GET_ITEM(s, i));
    Py_DECREF(s);
    return PyErr_Occurred() ? -1 : 0;
}

static int take(PyObject *kw, const char *key, double *dst, Py_ssize_t n)
{
    PyObject *v = PyDict_GetItemString(kw, key);
    if (v == NULL) {
        PyErr_Format(PyExc_TypeError, "Kernel needs %s", key);
        return -1;
    }
    return doubles(v, key, dst, n);
}

static int take_table(PyObject *kw, const char *key, Py_buffer *b, int *has)
{
    PyObject *v = PyDict_GetItemString(kw, key);
    if (v == NULL || v == Py_None)
        return 0;
    if (PyObject_GetBuffer(v, b, PyBUF_RECORDS_RO) < 0)
        return -1;
    *has = 1;
    if (b->ndim != 2 || b->shape[1] < 3 || b->shape[0] < 1 || b->itemsize != 8 || strcmp(b->format, "d") != 0) {
        PyErr_Format(PyExc_ValueError, "Kernel's %s must be an (n, 3) float64 array", key);
        return -1;
    }
    return 0;
}

static PyObject *take_fn(PyObject *kw, const char *key)
{
    PyObject *v = PyDict_GetItemString(kw, key);
    if (v == NULL || v == Py_None)
        return NULL;
    Py_INCREF(v);
    return v;
}

static void kernel_dealloc(Kernel *k)
{
    if (k->has_grid)
        PyBuffer_Release(&k->grid);
    if (k->has_force)
        PyBuffer_Release(&k->force);
    Py_XDECREF(k->orbit_fn);
    Py_XDECREF(k->field_fn);
    Py_XDECREF(k->dist_fn);
    Py_TYPE(k)->tp_free((PyObject *)k);
}

static int kernel_init(Kernel *k, PyObject *args, PyObject *kw)
{
    double v[6], kinds[5];
    if (PyTuple_GET_SIZE(args) != 0 || kw == NULL) {
        PyErr_SetString(PyExc_TypeError, "Kernel takes keyword arguments only");
        return -1;
    }
    if (take(kw, "J", k->J, 9) || take(kw, "Jinv", k->Ji, 9) || take(kw, "C", k->C, 12)
        || take(kw, "CJ", k->CJ, 12) || take(kw, "jrw", k->jrw, NW) || take(kw, "wheel", v, 6)
        || take(kw, "kinds", kinds, 5) || take(kw, "circular", &k->oa, 9) || take(kw, "grid_t0_rate", &k->gt0, 2)
        || take(kw, "dipole_field", &k->gmst0, 6) || take(kw, "surface", &k->st0, 4)
        || take(kw, "g1", k->g1, 12) || take(kw, "g2", k->g2, 12) || take(kw, "r", k->r, 12)
        || take(kw, "imbalance", &k->us, 2))
        return -1;
    k->fv = v[0], k->fc = v[1], k->fs = v[2], k->tmax = v[3], k->wmax = v[4], k->mu = v[5];
    k->gg = (int)kinds[0], k->orbit = (int)kinds[1], k->field = (int)kinds[2], k->dist = (int)kinds[3];
    k->jitter = (int)kinds[4];
    if (take_table(kw, "grid", &k->grid, &k->has_grid) || take_table(kw, "force", &k->force, &k->has_force))
        return -1;
    k->orbit_fn = take_fn(kw, "orbit_fn");
    k->field_fn = take_fn(kw, "field_fn");
    k->dist_fn = take_fn(kw, "dist_fn");
    if ((k->orbit == ORB_GRID && !k->has_grid) || (k->dist == DST_SURFACE && !k->has_force)
        || (k->orbit == ORB_PY && !k->orbit_fn) || (k->field == FLD_PY && !k->field_fn)
        || (k->dist == DST_PY && !k->dist_fn)) {
        PyErr_SetString(PyExc_ValueError, "Kernel: a kind without its table or callable");
        return -1;
    }
    return 0;
}

static double row(const Py_buffer *b, Py_ssize_t i, int j)
{
    return *(const double *)((const char *)b->buf + i * b->strides[0] + j * b->strides[1]);
}

static int floats3(PyObject *o, double *d)      /* a Python callback's 3 numbers as doubles (steals o) */
{
    int err;
    if (o == NULL)
        return -1;
    err = doubles(o, "a callback's result", d, 3);
    Py_DECREF(o);
    return err;
}

/* TiltedDipoleField.field_floats */
static void dipole_field(const Kernel *k, const double *r, double t, double *b)
{
    double th = k->gmst0 + k->omega_e * t, c = cos(th), s = sin(th);
    double m0 = c * k->fm[0] - s * k->fm[1], m1 = s * k->fm[0] + c * k->fm[1], m2 = k->fm[2];
    double x = r[0], y = r[1], z = r[2], rn = sqrt(x * x + y * y + z * z), kk, d;
    x = x / rn, y = y / rn, z = z / rn;
    kk = pow(k->r_earth / rn, 3.0);
    d = 3.0 * (m0 * x + m1 * y + m2 * z);
    b[0] = kk * (d * x - m0), b[1] = kk * (d * y - m1), b[2] = kk * (d * z - m2);
}

/* the position, field and surface force at time t */
static int environment(const Kernel *k, double t, int need_field, Env *e)
{
    if (k->orbit == ORB_NONE || !(k->gg || need_field)) {
        need_field = 0;
    } else if (k->orbit == ORB_CIRCULAR) {
        double u = k->ou0 + k->on * t, cu = cos(u), su = sin(u);
        for (int i = 0; i < 3; i++)
            e->r[i] = k->oa * (cu * k->op[i] + su * k->ow[i]);
    } else if (k->orbit == ORB_GRID) {
        double i = nearbyint((t - k->gt0) * k->grate), n1 = (double)(k->grid.shape[0] - 1);
        Py_ssize_t j = (Py_ssize_t)(i < 0.0 ? 0.0 : (i > n1 ? n1 : i));
        for (int c = 0; c < 3; c++)
            e->r[c] = row(&k->grid, j, c);
    } else if (k->orbit == ORB_PY) {
        if (floats3(PyObject_CallFunction(k->orbit_fn, "d", t), e->r))
            return -1;
    }
    if (need_field && k->field == FLD_DIPOLE) {
        dipole_field(k, e->r, t, e->b);
    } else if (need_field && k->field == FLD_PY) {
        if (floats3(PyObject_CallFunction(k->field_fn, "(ddd)d", e->r[0], e->r[1], e->r[2], t), e->b))
            return -1;
    }
    if (k->dist == DST_SURFACE) {
        double d = t - k->st0, n1 = (double)(k->force.shape[0] - 1);
        Py_ssize_t j = (Py_ssize_t)(d < 1.0 ? 0.0 : (d > n1 ? n1 : trunc(d)));
        for (int c = 0; c < 3; c++)
            e->f[c] = row(&k->force, j, c);
    }
    return 0;
}

static void dcm(const double *q, double *a)         /* A(q), Eq. 4.7, as _dcm_rows */
{
    double e1 = q[0], e2 = q[1], e3 = q[2], q4 = q[3];
    a[0] = q4 * q4 + e1 * e1 - e2 * e2 - e3 * e3, a[1] = 2 * (e1 * e2 + q4 * e3), a[2] = 2 * (e1 * e3 - q4 * e2);
    a[3] = 2 * (e1 * e2 - q4 * e3), a[4] = q4 * q4 - e1 * e1 + e2 * e2 - e3 * e3, a[5] = 2 * (e2 * e3 + q4 * e1);
    a[6] = 2 * (e1 * e3 + q4 * e2), a[7] = 2 * (e2 * e3 - q4 * e1), a[8] = q4 * q4 - e1 * e1 - e2 * e2 + e3 * e3;
}

static void mat3(const double *a, const double *v, double *o)
{
    for (int i = 0; i < 3; i++)
        o[i] = a[3 * i] * v[0] + a[3 * i + 1] * v[1] + a[3 * i + 2] * v[2];
}

/* Wheels.jitter's torque (N m, body) at relative speeds wrel and angles ang */
static void jitter(const Kernel *k, const double *wrel, const double *ang, double *tau)
{
    double tq[3][NW];
    for (int i = 0; i < NW; i++) {
        double w2 = wrel[i] * wrel[i], ca = cos(ang[i]), sa = sin(ang[i]), u[3], f[3], *r = (double *)k->r;
        for (int c = 0; c < 3; c++) {
            u[c] = k->g1[4 * c + i] * ca + k->g2[4 * c + i] * sa;
            f[c] = u[c] * (k->us * w2);
        }
        tq[0][i] = r[4 + i] * f[2] - r[8 + i] * f[1] + u[0] * (k->ud * w2);
        tq[1][i] = r[8 + i] * f[0] - r[i] * f[2] + u[1] * (k->ud * w2);
        tq[2][i] = r[i] * f[1] - r[4 + i] * f[0] + u[2] * (k->ud * w2);
    }
    for (int c = 0; c < 3; c++)
        tau[c] = tq[c][0] + tq[c][1] + tq[c][2] + tq[c][3];
}

/* Spacecraft._tau_ext: gravity gradient (Eq. 4.69-4.75), dipole (Eq. 4.71, 4.73), disturbance, jitter */
static int tau_ext(const Kernel *k, double t, const double *x, const double *m, const Env *e, const double *wrel,
                   double *tau)
{
    double a[9], tx = 0.0, ty = 0.0, tz = 0.0, d[3];
    dcm(x, a);
    if (k->orbit != ORB_NONE && (k->gg || m)) {
        if (k->gg) {
            double v[3], y[3], rn, kk;
            mat3(a, e->r, v);
            rn = pow(v[0] * v[0] + v[1] * v[1] + v[2] * v[2], 0.5);
            v[0] = v[0] / rn, v[1] = v[1] / rn, v[2] = v[2] / rn;
            mat3(k->J, v, y);
            kk = 3.0 * k->mu / pow(rn, 3.0);
            tx += kk * (v[1] * y[2] - v[2] * y[1]);
            ty += kk * (v[2] * y[0] - v[0] * y[2]);
            tz += kk * (v[0] * y[1] - v[1] * y[0]);
        }
        if (m && k->field != FLD_NONE) {
            double b[3];
            mat3(a, e->b, b);
            tx += m[1] * b[2] - m[2] * b[1];
            ty += m[2] * b[0] - m[0] * b[2];
            tz += m[0] * b[1] - m[1] * b[0];
        }
    }
    if (k->dist == DST_SURFACE) {
        double b[3];
        mat3(a, e->f, b);
        tx = tx + (k->cp[1] * b[2] - k->cp[2] * b[1]);
        ty = ty + (k->cp[2] * b[0] - k->cp[0] * b[2]);
        tz = tz + (k->cp[0] * b[1] - k->cp[1] * b[0]);
    } else if (k->dist == DST_PY) {
        if (floats3(PyObject_CallFunction(k->dist_fn, "d(dddd)(ddd)", t, x[0], x[1], x[2], x[3], x[4], x[5], x[6]),
                    d))
            return -1;
        tx = tx + d[0], ty = ty + d[1], tz = tz + d[2];
    }
    if (k->jitter) {
        jitter(k, wrel, x + 11, d);
        tx = tx + d[0], ty = ty + d[1], tz = tz + d[2];
    }
    tau[0] = tx, tau[1] = ty, tau[2] = tz;
    return 0;
}

/* the wheels' speeds relative to the body, W - C^T w */
static void wrel_of(const Kernel *k, const double *x, double *wrel)
{
    for (int i = 0; i < NW; i++)
        wrel[i] = x[7 + i] - (k->C[i] * x[4] + k->C[4 + i] * x[5] + k->C[8 + i] * x[6]);
}

/* Spacecraft.derivative: dx/dt (Eq. 4.10, 4.16, 4.55-4.56) with the motor torques tq held */
static int derivative(const Kernel *k, double t, const double *x, const double *tq, const double *m, const Env *e,
                      double *dx)
{
    const double *q = x, *w = x + 4, *W = x + 7, *C = k->C, *CJ = k->CJ, *J = k->J, *Ji = k->Ji;
    double wrel[NW], net[NW], h[3], tau[3], r[3];
    wrel_of(k, x, wrel);
    for (int i = 0; i < NW; i++)
        net[i] = tq[i] - (k->fv * wrel[i] + k->fc * tanh(wrel[i] * k->fs));
    for (int c = 0; c < 3; c++)
        h[c] = J[3 * c] * w[0] + J[3 * c + 1] * w[1] + J[3 * c + 2] * w[2]
               + (CJ[4 * c] * W[0] + CJ[4 * c + 1] * W[1] + CJ[4 * c + 2] * W[2] + CJ[4 * c + 3] * W[3]);
    if (tau_ext(k, t, x, m, e, wrel, tau))
        return -1;
    r[0] = tau[0] - (w[1] * h[2] - w[2] * h[1]) - (C[0] * net[0] + C[1] * net[1] + C[2] * net[2] + C[3] * net[3]);
    r[1] = tau[1] - (w[2] * h[0] - w[0] * h[2]) - (C[4] * net[0] + C[5] * net[1] + C[6] * net[2] + C[7] * net[3]);
    r[2] = tau[2] - (w[0] * h[1] - w[1] * h[0]) - (C[8] * net[0] + C[9] * net[1] + C[10] * net[2] + C[11] * net[3]);
    dx[0] = 0.5 * (q[3] * w[0] - (w[1] * q[2] - w[2] * q[1]));
    dx[1] = 0.5 * (q[3] * w[1] - (w[2] * q[0] - w[0] * q[2]));
    dx[2] = 0.5 * (q[3] * w[2] - (w[0] * q[1] - w[1] * q[0]));
    dx[3] = -0.5 * (w[0] * q[0] + w[1] * q[1] + w[2] * q[2]);
    mat3(Ji, r, dx + 4);
    for (int i = 0; i < NW; i++) {
        dx[7 + i] = net[i] / k->jrw[i];
        dx[11 + i] = wrel[i];
    }
    return 0;
}

static double sgn(double v) { return v > 0.0 ? 1.0 : (v < 0.0 ? -1.0 : v); }

/* Wheels.limit: the motor torques held over the step and the clip flags (bit i torque, bit 4 + i speed) */
static int limit(const Kernel *k, const double *x, const double *cmd, const char *enable, double dt, double *tq)
{
    int flags = 0;
    double wrel[NW];
    wrel_of(k, x, wrel);
    for (int i = 0; i < NW; i++) {
        double wr = wrel[i], u = enable[i] ? cmd[i] : 0.0, v = u < -k->tmax ? -k->tmax : (u > k->tmax ? k->tmax : u);
        double room = k->jrw[i] * (k->wmax - fabs(wr)) / dt;
        room = room > 0.0 ? room : 0.0;
        if (v != u)
            flags |= 1 << i;
        if (v * sgn(wr) > room) {
            v = sgn(v) * room;
            flags |= 1 << (4 + i);
        }
        tq[i] = v;
    }
    return flags;
}

static int get(PyObject *o, Py_buffer *b, Py_ssize_t n, int writable, const char *format, const char *what)
{
    if (PyObject_GetBuffer(o, b, (writable ? PyBUF_WRITABLE : 0) | PyBUF_FORMAT | PyBUF_C_CONTIGUOUS) < 0)
        return -1;
    if (b->len != n * b->itemsize || strcmp(b->format, format) != 0) {
        PyBuffer_Release(b);
        PyErr_Format(PyExc_ValueError, "step: %s must be %zd of format '%s'", what, n, format);
        return -1;
    }
    return 0;
}

/* step(t, dt, x, x_out, tq_out, cmd, enable, dipole) -> (|q| before renormalising, clip flags) */
static PyObject *kernel_step(Kernel *k, PyObject *const *a, Py_ssize_t na)
{
    Py_buffer bx, bo, bt, bc, be;
    double t, dt, m[3], k1[15], k2[15], k3[15], k4[15], s[15], *x, *xo, *tq, qn = 0.0;
    const double *mp;
    int flags = 0, err = -1, nb = 0;
    Env e0, eh, e1;
    if (na != 8) {
        PyErr_SetString(PyExc_TypeError, "step takes 8 arguments");
        return NULL;
    }
    t = PyFloat_AsDouble(a[0]);
    dt = PyFloat_AsDouble(a[1]);
    if (PyErr_Occurred())
        return NULL;
    mp = a[7] == Py_None ? NULL : m;
    if (mp && doubles(a[7], "dipole", m, 3) < 0)
        return NULL;
    if (get(a[2], &bx, 15, 0, "d", "x") || (nb++, get(a[3], &bo, 15, 1, "d", "x_out"))
        || (nb++, get(a[4], &bt, NW, 1, "d", "tq_out")) || (nb++, get(a[5], &bc, NW, 0, "d", "cmd"))
        || (nb++, get(a[6], &be, NW, 0, "?", "enable")))
        goto done;
    nb++;
    x = bx.buf, xo = bo.buf, tq = bt.buf;
    flags = limit(k, x, bc.buf, be.buf, dt, tq);
    if (environment(k, t, mp != NULL, &e0) || environment(k, t + 0.5 * dt, mp != NULL, &eh)
        || environment(k, t + dt, mp != NULL, &e1))
        goto done;
    if (derivative(k, t, x, tq, mp, &e0, k1))
        goto done;
    for (int i = 0; i < 15; i++)
        s[i] = x[i] + 0.5 * dt * k1[i];
    if (derivative(k, t + 0.5 * dt, s, tq, mp, &eh, k2))
        goto done;
    for (int i = 0; i < 15; i++)
        s[i] = x[i] + 0.5 * dt * k2[i];
    if (derivative(k, t + 0.5 * dt, s, tq, mp, &eh, k3))
        goto done;
    for (int i = 0; i < 15; i++)
        s[i] = x[i] + dt * k3[i];
    if (derivative(k, t + dt, s, tq, mp, &e1, k4))
        goto done;
    for (int i = 0; i < 15; i++)
        xo[i] = x[i] + dt / 6.0 * (k1[i] + 2.0 * (k2[i] + k3[i]) + k4[i]);
    /* |q| as numpy's x[0:4] @ x[0:4] gives it on these machines (OpenBLAS's ddot: fused multiply-adds) */
    qn = sqrt(fma(xo[3], xo[3], fma(xo[2], xo[2], fma(xo[1], xo[1], xo[0] * xo[0]))));
    for (int i = 0; i < 4; i++)
        xo[i] = xo[i] / qn;
    err = 0;
done:
    if (nb > 4) PyBuffer_Release(&be);
    if (nb > 3) PyBuffer_Release(&bc);
    if (nb > 2) PyBuffer_Release(&bt);
    if (nb > 1) PyBuffer_Release(&bo);
    if (nb > 0) PyBuffer_Release(&bx);
    return err ? NULL : Py_BuildValue("di", qn, flags);
}

/* torque(t, x, dipole) -> tau_ext (N m, body) at time t and state x (Spacecraft.external_torque) */
static PyObject *kernel_torque(Kernel *k, PyObject *const *a, Py_ssize_t na)
{
    Py_buffer bx;
    double t, m[3], tau[3], wrel[NW];
    const double *mp;
    int err;
    Env e;
    if (na != 3) {
        PyErr_SetString(PyExc_TypeError, "torque takes 3 arguments");
        return NULL;
    }
    t = PyFloat_AsDouble(a[0]);
    mp = a[2] == Py_None ? NULL : m;
    if ((t == -1.0 && PyErr_Occurred()) || (mp && doubles(a[2], "dipole", m, 3) < 0)
        || get(a[1], &bx, 15, 0, "d", "x"))
        return NULL;
    wrel_of(k, bx.buf, wrel);
    err = environment(k, t, mp != NULL, &e) || tau_ext(k, t, bx.buf, mp, &e, wrel, tau);
    PyBuffer_Release(&bx);
    return err ? NULL : Py_BuildValue("(ddd)", tau[0], tau[1], tau[2]);
}

static PyMethodDef kernel_methods[] = {
    {"torque", (PyCFunction)(void (*)(void))kernel_torque, METH_FASTCALL,
     "torque(t, x, dipole) -> (tx, ty, tz): the external torque (N m, body) at time t and state x (15)"},
    {"step", (PyCFunction)(void (*)(void))kernel_step, METH_FASTCALL,
     "step(t, dt, x, x_out, tq_out, cmd, enable, dipole) -> (|q| before renormalising, clip flags): one RK4 step "
     "of dt from x (15) into x_out, the wheels' limited torques into tq_out (flag bit i: wheel i's torque clipped, "
     "bit 4 + i: its speed limit cut it); dipole a 3-sequence (A m^2) or None"},
    {NULL}
};

static PyTypeObject KernelType = {
    PyVarObject_HEAD_INIT(NULL, 0)
    .tp_name = "emulator.spacecraft._truth.Kernel",
    .tp_basicsize = sizeof(Kernel),
    .tp_flags = Py_TPFLAGS_DEFAULT,
    .tp_doc = "The truth's constants and environment (built by emulator.spacecraft.dynamics.kernel_args).",
    .tp_new = PyType_GenericNew,
    .tp_init = (initproc)kernel_init,
    .tp_dealloc = (destructor)kernel_dealloc,
    .tp_methods = kernel_methods,
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, .m_name = "_truth", .m_doc = "The truth's RK4 step in C.", .m_size = -1,
};

PyMODINIT_FUNC PyInit__truth(void)
{
    PyObject *mod;
    if (PyType_Ready(&KernelType) < 0)
        return NULL;
    mod = PyModule_Create(&module);
    if (mod == NULL)
        return NULL;
    Py_INCREF(&KernelType);
    if (PyModule_AddObject(mod, "Kernel", (PyObject *)&KernelType) < 0 || PyModule_AddIntConstant(mod, "API", API) < 0) {
        Py_DECREF(&KernelType);
        Py_DECREF(mod);
        return NULL;
    }
    return mod;
}
