// adcsk.c's kernels as a CPython extension, ``firmware.adcs._adcsk`` (pyproject.toml; optional: without a C
// compiler the Python forms run). The one source: the few MicroPython API calls adcsk.c makes are given here over
// CPython's, then adcsk.c is included as it is. linalg.py selects the module on CPython.
//
// A MicroPython raise unwinds out of the kernel (nlr); here it sets the Python error and jumps back to the call
// (sigsetjmp: no object is held across it). A float buffer's pointer is taken and its view released at once: no
// Python code runs during a call (floats and ints are read without __float__ or __index__), so the buffer can
// be neither resized nor freed before the kernel returns. Anything else where a buffer, float or int is due is a
// TypeError, on which linalg.either runs the Python form (a test's lists of floats or of numpy.float32).

#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <setjmp.h>
#include <stdbool.h>

typedef PyObject *mp_obj_t;
typedef Py_ssize_t mp_int_t;
typedef struct {
    void *buf;
    size_t len;
    int typecode;
} mp_buffer_info_t;

#define MP_BUFFER_RW 0
#define MP_ERROR_TEXT(s) s
#define mp_const_none Py_None
#define mp_const_true Py_True
#define mp_const_false Py_False
#define mp_obj_new_bool(b) ((b) ? Py_True : Py_False)
#define mp_type_list PyList_Type
#define mp_type_tuple PyTuple_Type
#define mp_obj_is_type(o, t) Py_IS_TYPE((o), (t))

static sigjmp_buf *escape;                  // the running call's (the GIL is held throughout)

static void raise_to_call(PyObject *type, const char *msg) {
    if (msg != NULL) {
        PyErr_SetString(type, msg);
    }
    siglongjmp(*escape, 1);
}
#define mp_raise_TypeError(msg) raise_to_call(PyExc_TypeError, msg)
#define mp_raise_ValueError(msg) raise_to_call(PyExc_ValueError, msg)

static void mp_get_buffer_raise(mp_obj_t o, mp_buffer_info_t *bi, int flags) {
    (void)flags;
    Py_buffer view;
    if (PyObject_GetBuffer(o, &view, PyBUF_WRITABLE | PyBUF_FORMAT) != 0) {
        PyErr_Clear();
        raise_to_call(PyExc_TypeError, "adcsk: a float array ('f' or 'd') is needed");
    }
    bi->buf = view.buf;
    bi->len = (size_t)view.len;
    bi->typecode = (view.format != NULL && view.format[0] != 0 && view.format[1] == 0) ? view.format[0] : 0;
    PyBuffer_Release(&view);
}

static double mp_obj_get_float_to_d(mp_obj_t o) {
    if (PyFloat_Check(o)) {
        return PyFloat_AS_DOUBLE(o);
    }
    if (PyLong_CheckExact(o)) {
        double v = PyLong_AsDouble(o);
        if (v == -1.0 && PyErr_Occurred()) {
            raise_to_call(NULL, NULL);
        }
        return v;
    }
    raise_to_call(PyExc_TypeError, "adcsk: a float is needed");
    return 0.0;
}

static mp_int_t mp_obj_get_int(mp_obj_t o) {
    if (!PyLong_CheckExact(o)) {
        raise_to_call(PyExc_TypeError, "adcsk: an int is needed");
    }
    Py_ssize_t v = PyLong_AsSsize_t(o);
    if (v == -1 && PyErr_Occurred()) {
        raise_to_call(NULL, NULL);
    }
    return v;
}

static void mp_obj_get_array(mp_obj_t o, size_t *len, mp_obj_t **items) {
    if (!PyList_CheckExact(o) && !PyTuple_CheckExact(o)) {
        raise_to_call(PyExc_TypeError, "adcsk: a list is needed");
    }
    *len = (size_t)PySequence_Fast_GET_SIZE(o);
    *items = PySequence_Fast_ITEMS(o);
}

// a kernel: its C function (by arity) and how many arguments it takes
typedef struct {
    mp_obj_t (*f2)(mp_obj_t, mp_obj_t);
    mp_obj_t (*f3)(mp_obj_t, mp_obj_t, mp_obj_t);
    mp_obj_t (*fv)(size_t, const mp_obj_t *);
    Py_ssize_t lo, hi;
} kernel_t;

#define MP_DEFINE_CONST_FUN_OBJ_2(obj, f) const kernel_t obj = {.f2 = f, .lo = 2, .hi = 2}
#define MP_DEFINE_CONST_FUN_OBJ_3(obj, f) const kernel_t obj = {.f3 = f, .lo = 3, .hi = 3}
#define MP_DEFINE_CONST_FUN_OBJ_VAR_BETWEEN(obj, a, b, f) const kernel_t obj = {.fv = f, .lo = a, .hi = b}

#define ADCSK_CPYTHON 1
#include "adcsk.c"

static PyObject *call(const kernel_t *k, PyObject *const *args, Py_ssize_t n) {
    if (n < k->lo || n > k->hi) {
        PyErr_Format(PyExc_TypeError, "adcsk: %zd arguments given, %zd to %zd taken", n, k->lo, k->hi);
        return NULL;
    }
    sigjmp_buf here;
    sigjmp_buf *outer = escape;
    escape = &here;
    if (sigsetjmp(here, 0) != 0) {
        escape = outer;
        return NULL;
    }
    PyObject *r = k->fv != NULL ? k->fv((size_t)n, args)
                  : k->f3 != NULL ? k->f3(args[0], args[1], args[2]) : k->f2(args[0], args[1]);
    escape = outer;
    Py_INCREF(r);                               // None, True or False
    return r;
}

// a Python function per kernel, named as the MicroPython module's (the qstr's name less "MP_QSTR_")
#define WRAP(q, o) \
    static PyObject *py_##o(PyObject *self, PyObject *const *args, Py_ssize_t n) { \
        (void)self; \
        return call(&o, args, n); \
    }
ADCSK_FUNCS(WRAP)

#define METHOD(q, o) {#q + 8, (PyCFunction)(void (*)(void))py_##o, METH_FASTCALL, NULL},
static PyMethodDef methods[] = {
    ADCSK_FUNCS(METHOD)
    {NULL, NULL, 0, NULL}
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "_adcsk", "The ADCS kernels (firmware/adcs/native/adcsk.c) for CPython.", -1, methods,
    NULL, NULL, NULL, NULL
};

PyMODINIT_FUNC PyInit__adcsk(void) {
    return PyModule_Create(&module);
}
