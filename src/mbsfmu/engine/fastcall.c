/* The in-process right-hand side called from Python without ctypes' per-argument conversions (engine/__init__.py:
 * Instance.rhs; issue 26): ctypes spends about 0.5 µs on mbs_rhs's four arguments and numpy's `.ctypes.data` 0.8 µs
 * per array, more than a small robot's whole right-hand side. A CPython extension of one function, which calls
 * mbs_rhs at the address it is given, in the engine library ctypes loaded (one engine, one seam: the instances
 * stay ctypes'), after reading the arrays through the buffer protocol and checking them (float64, C-contiguous, n
 * numbers, `out` writable); whatever it does not take as it is goes to the Python call it is given. The instance
 * address is valid as long as the call is: that Python call holds the instance (engine/__init__.py: _Engine).
 * Built by build.py (fastcall_path) where the Python headers are; without them Instance.rhs is that Python call. */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <string.h>

typedef int (*rhs_fn)(void *, double, const double *, double *);

/* b: o's buffer if it holds at least n float64 numbers in one C-contiguous block (flags: PyBUF_WRITABLE for out);
 * -1 (an exception set) if not */
static int doubles(PyObject *o, Py_buffer *b, int flags, Py_ssize_t n)
{
    if (PyObject_GetBuffer(o, b, PyBUF_C_CONTIGUOUS | PyBUF_FORMAT | flags) < 0) return -1;
    const char *f = b->format ? b->format : "B";
    if (*f == '@' || *f == '=' || *f == '<') f++;  /* (native or little-endian: the engine's doubles) */
    if (b->itemsize == 8 && strcmp(f, "d") == 0 && b->len >= n * 8) return 0;
    PyBuffer_Release(b);
    PyErr_SetString(PyExc_ValueError, "not n float64 numbers in one contiguous block");
    return -1;
}

/* rhs(address of mbs_rhs, instance address, n, slow, t, x[, out]) -> out: the engine's ẋ into out; anything
 * else — no out, arrays it cannot take as they are, a status other than OK — is slow(t, x[, out])'s, which converts,
 * evaluates and raises with the engine's message (engine/__init__.py: Instance._rhs_slow) */
static PyObject *rhs(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    (void)self;
    if (nargs != 6 && nargs != 7)
        return PyErr_Format(PyExc_TypeError, "rhs(t, x, out=None): 2 or 3 arguments, got %zd", nargs - 4);
    rhs_fn engine_rhs = (rhs_fn)PyLong_AsVoidPtr(args[0]);
    void *inst = PyLong_AsVoidPtr(args[1]);
    const Py_ssize_t n = PyLong_AsSsize_t(args[2]);
    if (PyErr_Occurred()) return NULL;
    PyObject *out = nargs == 7 ? args[6] : Py_None;
    const double t = PyFloat_AsDouble(args[4]);
    Py_buffer x, o;
    if (engine_rhs && inst && n >= 0 && out != Py_None && !PyErr_Occurred() && doubles(args[5], &x, 0, n) == 0) {
        if (doubles(out, &o, PyBUF_WRITABLE, n) == 0) {
            const int status = engine_rhs(inst, t, x.buf, o.buf);
            PyBuffer_Release(&o);
            PyBuffer_Release(&x);
            if (status == 0) {
                Py_INCREF(out);
                return out;
            }
        } else
            PyBuffer_Release(&x);
    }
    PyErr_Clear();
    return PyObject_Vectorcall(args[3], args + 4, (size_t)(nargs - 4), NULL);
}

static PyMethodDef methods[] = {
    {"rhs", (PyCFunction)(void (*)(void))rhs, METH_FASTCALL, "rhs(mbs_rhs, instance, n, slow, t, x[, out]) -> out"},
    {NULL, NULL, 0, NULL}};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_mbsfmu_fastcall", NULL, -1, methods,
                                    NULL, NULL, NULL, NULL};

PyMODINIT_FUNC PyInit__mbsfmu_fastcall(void) { return PyModule_Create(&module); }
