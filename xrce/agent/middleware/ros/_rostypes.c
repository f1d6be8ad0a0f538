/* The agent's ROS type-support extension, xrce.agent.middleware.ros._rostypes: type supports and
 * conversions for the agent's raw interface classes (xrce.agent.middleware.ros.raw_types), of
 * types known only by name (_named_types.c), a replier's requests and replies as CDR bytes
 * (_services.c), and a DDS participant made without the GIL
 * (xrce.agent.middleware.ros.participant). It is apart from the engine's compiled receive path
 * (xrce.agent.engine.compiled._fastpath): the protocol engine holds no ROS type-support code, and either
 * extension may be missing without the other (setup.py). rcl, rmw and rcutils are not linked:
 * their functions are looked up in the librcl rclpy already loaded. */
#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include <dlfcn.h>
#include <stdbool.h>
#include <stdint.h>

#include "_rostypes.h"

/* Looked up through librcl: a handle's lookup covers the libraries it depends on, so this finds
 * rmw's functions in whichever rmw library rcl is linked to (librmw_implementation where ROS
 * dispatches at run time, the rmw of the ROS wheels directly) and rcutils'. */
void *xrce_rcl_symbol(const char *name) {
    void *library = dlopen("librcl.so", RTLD_NOW | RTLD_NOLOAD);
    if (library == NULL) return NULL;
    void *found = dlsym(library, name);
    dlclose(library);  /* NOLOAD took a reference; rclpy holds its own */
    return found;
}

/* message_type_support(library, symbol): the capsule of a message's C type support (what a
   generated message class's _TYPE_SUPPORT holds), from the package's lib*__rosidl_typesupport_c.so
   alone, for the agent's raw message types (xrce.agent.middleware.ros.types). The package's Python
   extension that also provides it links the package's and its dependencies' rosidl_generator_py
   libraries: 2-3 ms and ~0.12 MB resident more per package, for conversions the agent never makes.
   The library stays loaded: the capsule points into it. */
/* ``symbol`` of the library at ``path``, loaded (and left loaded: what it gives points into it);
 * NULL with ImportError set. */
static void *library_symbol(const char *path, const char *symbol) {
    void *library;
    Py_BEGIN_ALLOW_THREADS
    library = dlopen(path, RTLD_NOW | RTLD_LOCAL);
    Py_END_ALLOW_THREADS
    if (library == NULL) {
        PyErr_SetString(PyExc_ImportError, dlerror());
        return NULL;
    }
    void *found = dlsym(library, symbol);
    if (found == NULL) {
        PyErr_SetString(PyExc_ImportError, dlerror());
        dlclose(library);
    }
    return found;
}

static PyObject *message_type_support(PyObject *module, PyObject *args) {
    (void)module;
    const char *path, *symbol;
    if (!PyArg_ParseTuple(args, "ss", &path, &symbol)) return NULL;
    const void *(*get_handle)(void) = (const void *(*)(void))library_symbol(path, symbol);
    if (get_handle == NULL) return NULL;
    const void *handle = get_handle();
    if (handle == NULL) {
        PyErr_Format(PyExc_ImportError, "%s returned no type support", symbol);
        return NULL;
    }
    return PyCapsule_New((void *)handle, NULL, NULL);
}

/* What a raw message type has for rclpy's four conversion functions (create, destroy, from and
   to Python), which rclpy.type_support checks are set before it makes a publisher or
   subscription: the agent only publishes and takes serialized bytes, so none may ever run. One
   that is called anyway fails as a conversion does, with a Python error, never a crash. */
static void *no_ros_message(void) {
    return NULL;  /* rclpy raises MemoryError */
}

static void no_destroy(void *message) {
    (void)message;
}

static bool no_convert_from_py(PyObject *object, void *message) {
    (void)object;
    (void)message;
    PyErr_SetString(PyExc_TypeError, "the agent's raw message types take serialized bytes only");
    return false;
}

static PyObject *no_convert_to_py(void *message) {
    (void)message;
    PyErr_SetString(PyExc_TypeError, "the agent's raw message types give serialized bytes only");
    return NULL;
}

/* participant_node(context, name) -> address or None; participant_node_destroy(address) -> bool.
   An rmw node of an rcl context (the rcl_context_t address, rclpy's Context.handle.pointer), made
   with the GIL released: rmw makes a context's DDS participant with its first node, and rclpy's
   own node creation holds the GIL for all of it (xrce.agent.middleware.ros.participant). The
   three-argument rmw_create_node is Humble's and later; rmw is found through rcl, already loaded. */
typedef void *(*rmw_context_fn)(void *);
typedef void *(*rmw_create_node_fn)(void *, const char *, const char *);
typedef int (*rmw_destroy_node_fn)(void *);

static PyObject *participant_node(PyObject *module, PyObject *args) {
    unsigned long long context;
    const char *name;
    if (!PyArg_ParseTuple(args, "Ks", &context, &name)) return NULL;
    rmw_context_fn get_rmw_context = (rmw_context_fn)xrce_rcl_symbol("rcl_context_get_rmw_context");
    rmw_create_node_fn create = (rmw_create_node_fn)xrce_rcl_symbol("rmw_create_node");
    reset_error_fn reset_error = (reset_error_fn)xrce_rcl_symbol("rcutils_reset_error");
    if (get_rmw_context == NULL || create == NULL || reset_error == NULL) Py_RETURN_NONE;
    void *node = NULL;
    Py_BEGIN_ALLOW_THREADS
    void *rmw_context = get_rmw_context((void *)(uintptr_t)context);
    if (rmw_context != NULL) node = create(rmw_context, name, "/");
    if (node == NULL) reset_error();  /* the rclpy node's own error, if it fails too, is reported */
    Py_END_ALLOW_THREADS
    if (node == NULL) Py_RETURN_NONE;
    return PyLong_FromVoidPtr(node);
}

static PyObject *participant_node_destroy(PyObject *module, PyObject *address) {
    void *node = PyLong_AsVoidPtr(address);
    if (node == NULL) {
        if (PyErr_Occurred()) return NULL;
        Py_RETURN_FALSE;
    }
    rmw_destroy_node_fn destroy = (rmw_destroy_node_fn)xrce_rcl_symbol("rmw_destroy_node");
    reset_error_fn reset_error = (reset_error_fn)xrce_rcl_symbol("rcutils_reset_error");
    if (destroy == NULL || reset_error == NULL) Py_RETURN_FALSE;
    int ret;
    Py_BEGIN_ALLOW_THREADS
    ret = destroy(node);
    if (ret != 0) reset_error();
    Py_END_ALLOW_THREADS
    return PyBool_FromLong(ret == 0);
}

/* raw_type_conversions() -> (create, convert_from_py, convert_to_py, destroy) capsules. */
static PyObject *raw_type_conversions(PyObject *module, PyObject *unused) {
    return Py_BuildValue("(NNNN)", PyCapsule_New((void *)no_ros_message, NULL, NULL),
                         PyCapsule_New((void *)no_convert_from_py, NULL, NULL),
                         PyCapsule_New((void *)no_convert_to_py, NULL, NULL),
                         PyCapsule_New((void *)no_destroy, NULL, NULL));
}

/* library_function(path, symbol) -> a capsule of the function ``symbol`` of the library at
 * ``path``, not called: a generated message's ``<pkg>__srv__<Name>_Request__create`` and
 * ``__destroy`` (rosidl_generator_c) have the signatures rclpy calls through a message class's
 * ``_CREATE_ROS_MESSAGE`` and ``_DESTROY_ROS_MESSAGE`` (no argument, returns the message; takes
 * the message). The library stays loaded, as the type support libraries it goes with. */
static PyObject *library_function(PyObject *module, PyObject *args) {
    (void)module;
    const char *path, *symbol;
    if (!PyArg_ParseTuple(args, "ss", &path, &symbol)) return NULL;
    void *function = library_symbol(path, symbol);
    return function ? PyCapsule_New(function, NULL, NULL) : NULL;
}

static PyMethodDef ros_support_methods[] = {
    {"raw_type_conversions", raw_type_conversions, METH_NOARGS, NULL},
    {"message_type_support", message_type_support, METH_VARARGS, NULL},
    {"library_function", library_function, METH_VARARGS, NULL},
    {"participant_node", participant_node, METH_VARARGS, NULL},
    {"participant_node_destroy", participant_node_destroy, METH_O, NULL},
    {NULL},
};

/* CRC-32 of this folder's C sources, given by setup.py (xrce.agent.middleware.ros.compiled
 * compares it with them). */
#ifndef XRCE_SOURCE_CRC
#define XRCE_SOURCE_CRC "unknown"
#endif

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "xrce.agent.middleware.ros._rostypes", NULL, -1, ros_support_methods,
};

PyMODINIT_FUNC PyInit__rostypes(void) {
    PyObject *m = PyModule_Create(&module);
    if (m == NULL) return NULL;
    if (xrce_services_add(m) < 0 || xrce_named_types_add(m) < 0 ||
        PyModule_AddStringConstant(m, "SOURCE_CRC", XRCE_SOURCE_CRC) < 0) {
        Py_DECREF(m);
        return NULL;
    }
    return m;
}
