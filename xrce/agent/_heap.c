/* malloc_trim(0) for xrce/agent/heap.py: the C heap's free pages given back to the system once
 * the agent's start-up or a burst is over, or a domain's DDS participant is gone. An extension of
 * its own rather than ctypes (the ctypes package, once imported, stays in the process: 0.57 MB of
 * classes) and rather than a function of the engine's receive path (heap.py is a ground module:
 * the engine and the middleware both call it, and it imports neither). */
#define PY_SSIZE_T_CLEAN
#include <Python.h>

#if defined(__GLIBC__)
#include <malloc.h>
#endif

static PyObject *return_free_heap(PyObject *module, PyObject *unused) {
#if defined(__GLIBC__)
    malloc_trim(0);
    Py_RETURN_TRUE;
#else
    Py_RETURN_FALSE;
#endif
}

static PyMethodDef module_methods[] = {
    {"return_free_heap", return_free_heap, METH_NOARGS,
     "malloc_trim(0) where glibc has it: True if it ran"},
    {NULL},
};

/* CRC-32 of this folder's C sources, given by setup.py as for the other extensions; nothing
 * compares it: a stale build of this one function still trims the same heap. */
#ifndef XRCE_SOURCE_CRC
#define XRCE_SOURCE_CRC "unknown"
#endif

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "xrce.agent._heap", NULL, -1, module_methods,
};

PyMODINIT_FUNC PyInit__heap(void) {
    PyObject *m = PyModule_Create(&module);
    if (m == NULL) return NULL;
    if (PyModule_AddStringConstant(m, "SOURCE_CRC", XRCE_SOURCE_CRC) < 0) {
        Py_DECREF(m);
        return NULL;
    }
    return m;
}
