/* A replier's requests and replies as CDR bytes through rclpy's own service calls.
 *
 * Why: a request for a firmware's replier went rcl -> a C message -> rclpy's Python message ->
 * serialize_message -> bytes, and its reply bytes -> deserialize_message -> a Python message ->
 * rclpy's C message -> rcl_send_response: two conversions through Python objects per leg, for
 * bytes the agent only forwards (bench/microros/service_roundtrip.py). Here the conversions rclpy looks
 * up on a message class's metaclass are replaced for the agent's replier types
 * (xrce.agent.middleware.ros.services): the request taken by rclpy's service_take_request is
 * serialized straight from its C message (rmw_serialize, as serialize_message does), and a reply
 * object carrying CDR bytes is deserialized straight into the C message rclpy then hands to
 * rcl_send_response (rmw_deserialize, as deserialize_message does). The bytes are those of the
 * Python conversions; rclpy keeps its locking, its request header and its error handling.
 *
 * rclpy calls a message's to-Python conversion with the C message alone, so the function has
 * to know the type by itself: a small table of slots, one per request type, each with a function
 * of its own. A type beyond the table keeps the Python conversions (None from
 * raw_request_conversion).
 *
 * rmw and rcutils are not linked, as rcl is not for the engine's _fastpath.c: their functions are
 * looked up in the libraries rclpy already loaded.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include <dlfcn.h>
#include <stdbool.h>
#include <stdint.h>
#include <string.h>

#include "_rostypes.h"

/* rcutils_allocator_t and rcutils_uint8_array_t (rmw_serialized_message_t) as rcutils declares
 * them. */
typedef struct {
    void *allocate, *deallocate, *reallocate, *zero_allocate, *state;
} allocator_t;
typedef struct {
    uint8_t *buffer;
    size_t buffer_length;
    size_t buffer_capacity;
    allocator_t allocator;
} byte_array_t;

typedef int (*serialize_fn)(const void *message, const void *type_support, byte_array_t *out);
typedef int (*deserialize_fn)(const byte_array_t *in, const void *type_support, void *message);
typedef allocator_t (*default_allocator_fn)(void);
typedef int (*array_init_fn)(byte_array_t *array, size_t capacity, const allocator_t *allocator);
typedef int (*array_fini_fn)(byte_array_t *array);

static serialize_fn rmw_serialize;
static deserialize_fn rmw_deserialize;
static default_allocator_fn default_allocator;
static array_init_fn array_init;
static array_fini_fn array_fini;
static reset_error_fn reset_error;

#define ENCAPSULATION 4  /* the CDR encapsulation header, which XRCE samples do not carry */
#define INITIAL_CAPACITY 1024

static bool resolved(void) {
    if (rmw_serialize && rmw_deserialize && default_allocator && array_init && array_fini &&
        reset_error)
        return true;
    rmw_serialize = (serialize_fn)xrce_rcl_symbol("rmw_serialize");
    rmw_deserialize = (deserialize_fn)xrce_rcl_symbol("rmw_deserialize");
    default_allocator = (default_allocator_fn)xrce_rcl_symbol("rcutils_get_default_allocator");
    array_init = (array_init_fn)xrce_rcl_symbol("rcutils_uint8_array_init");
    array_fini = (array_fini_fn)xrce_rcl_symbol("rcutils_uint8_array_fini");
    reset_error = (reset_error_fn)xrce_rcl_symbol("rcutils_reset_error");
    return rmw_serialize && rmw_deserialize && default_allocator && array_init && array_fini &&
           reset_error;
}

static const void *capsule_pointer(PyObject *capsule) {
    if (!PyCapsule_CheckExact(capsule)) {
        PyErr_SetString(PyExc_TypeError, "expected a type support capsule");
        return NULL;
    }
    return PyCapsule_GetPointer(capsule, PyCapsule_GetName(capsule));
}

/* ----------------------------------------------------------------- requests: C message -> bytes */

#define REQUEST_SLOTS 64
static const void *request_types[REQUEST_SLOTS];  /* message type support of each slot */

static PyObject *request_to_cdr(int slot, void *message) {
    allocator_t allocator = default_allocator();
    byte_array_t cdr;
    memset(&cdr, 0, sizeof cdr);
    if (array_init(&cdr, INITIAL_CAPACITY, &allocator) != 0) {
        reset_error();
        return PyErr_NoMemory();
    }
    /* Fast CDR leaves alignment padding as it finds the buffer: zeroed here, the padding goes
     * out as zeros (serialize_message's went out as whatever its heap held). rmw resizes the
     * buffer only when it is too small; then it is zeroed whole and the request serialized
     * again. */
    memset(cdr.buffer, 0, cdr.buffer_capacity);
    PyObject *result = NULL;
    int failed = rmw_serialize(message, request_types[slot], &cdr) != 0;
    if (!failed && cdr.buffer_capacity > INITIAL_CAPACITY) {
        memset(cdr.buffer, 0, cdr.buffer_capacity);
        cdr.buffer_length = 0;
        failed = rmw_serialize(message, request_types[slot], &cdr) != 0;
    }
    if (failed) {
        reset_error();
        PyErr_SetString(PyExc_RuntimeError, "the request could not be serialized");
    } else if (cdr.buffer_length < ENCAPSULATION) {
        PyErr_SetString(PyExc_RuntimeError, "the serialized request has no encapsulation");
    } else {
        result = PyBytes_FromStringAndSize((const char *)cdr.buffer + ENCAPSULATION,
                                           (Py_ssize_t)(cdr.buffer_length - ENCAPSULATION));
    }
    array_fini(&cdr);
    return result;
}

/* One function per slot: rclpy passes the C message and nothing else. */
#define SLOT(g, i) \
    static PyObject *request_to_cdr_##g##_##i(void *m) { return request_to_cdr((g) * 8 + (i), m); }
#define SLOTS8(g) SLOT(g, 0) SLOT(g, 1) SLOT(g, 2) SLOT(g, 3) SLOT(g, 4) SLOT(g, 5) SLOT(g, 6) \
    SLOT(g, 7)
SLOTS8(0) SLOTS8(1) SLOTS8(2) SLOTS8(3) SLOTS8(4) SLOTS8(5) SLOTS8(6) SLOTS8(7)
#define ENTRIES8(g) request_to_cdr_##g##_0, request_to_cdr_##g##_1, request_to_cdr_##g##_2, \
    request_to_cdr_##g##_3, request_to_cdr_##g##_4, request_to_cdr_##g##_5, \
    request_to_cdr_##g##_6, request_to_cdr_##g##_7
static PyObject *(*const request_converters[REQUEST_SLOTS])(void *) = {
    ENTRIES8(0), ENTRIES8(1), ENTRIES8(2), ENTRIES8(3), ENTRIES8(4), ENTRIES8(5), ENTRIES8(6),
    ENTRIES8(7),
};

/* A raw request class has no Python message to convert from: rclpy never asks for it when it
 * takes a request; anything else that tries fails as a conversion does. */
static bool request_from_py(PyObject *object, void *message) {
    (void)object;
    (void)message;
    PyErr_SetString(PyExc_TypeError, "the agent's raw service requests are taken, never sent");
    return false;
}

/* raw_request_conversion(type_support) -> (convert_to_py, convert_from_py) capsules for a
 * request class whose messages rclpy takes as the CDR bytes behind the encapsulation (the
 * slot of that type support, taken on first use), or None: rmw is not loaded, or every slot
 * serves another type. */
static PyObject *raw_request_conversion(PyObject *module, PyObject *capsule) {
    (void)module;
    const void *type_support = capsule_pointer(capsule);
    if (type_support == NULL) return NULL;
    if (!resolved()) Py_RETURN_NONE;
    int slot = -1;
    for (int i = 0; i < REQUEST_SLOTS && slot < 0; i++) {
        if (request_types[i] == type_support) slot = i;
        else if (request_types[i] == NULL) {
            request_types[i] = type_support;
            slot = i;
        }
    }
    if (slot < 0) Py_RETURN_NONE;
    return Py_BuildValue("(NN)", PyCapsule_New((void *)request_converters[slot], NULL, NULL),
                         PyCapsule_New((void *)request_from_py, NULL, NULL));
}

/* ------------------------------------------------------------------ replies: bytes -> C message */

/* rclpy's convert_from_py for a raw reply object: its ``cdr`` (the sample with its
 * encapsulation) deserialized into the C message rclpy created for its class, whose
 * ``_TYPE_SUPPORT`` names the type. */
static bool reply_from_py(PyObject *object, void *message) {
    PyObject *cdr = PyObject_GetAttrString(object, "cdr");
    if (cdr == NULL) return false;
    PyObject *type_capsule = PyObject_GetAttrString((PyObject *)Py_TYPE(object), "_TYPE_SUPPORT");
    bool done = false;
    Py_buffer view;
    const void *type_support = type_capsule ? capsule_pointer(type_capsule) : NULL;
    if (type_support != NULL && PyObject_GetBuffer(cdr, &view, PyBUF_SIMPLE) == 0) {
        byte_array_t in;
        memset(&in, 0, sizeof in);
        in.buffer = view.buf;
        in.buffer_length = in.buffer_capacity = (size_t)view.len;
        in.allocator = default_allocator();
        if (rmw_deserialize(&in, type_support, message) == 0) {
            done = true;
        } else {
            reset_error();
            PyErr_SetString(PyExc_ValueError, "the reply does not deserialize as its type");
        }
        PyBuffer_Release(&view);
    }
    Py_XDECREF(type_capsule);
    Py_DECREF(cdr);
    return done;
}

static PyObject *reply_to_py(void *message) {
    (void)message;
    PyErr_SetString(PyExc_TypeError, "the agent's raw service replies are sent, never taken");
    return NULL;
}

/* raw_reply_conversion() -> (convert_to_py, convert_from_py) capsules for a reply class whose
 * objects carry CDR bytes (``cdr``), or None when rmw is not loaded. */
static PyObject *raw_reply_conversion(PyObject *module, PyObject *unused) {
    (void)module;
    (void)unused;
    if (!resolved()) Py_RETURN_NONE;
    return Py_BuildValue("(NN)", PyCapsule_New((void *)reply_to_py, NULL, NULL),
                         PyCapsule_New((void *)reply_from_py, NULL, NULL));
}

static PyMethodDef service_methods[] = {
    {"raw_request_conversion", raw_request_conversion, METH_O, NULL},
    {"raw_reply_conversion", raw_reply_conversion, METH_NOARGS, NULL},
    {NULL},
};

int xrce_services_add(PyObject *module) {
    return PyModule_AddFunctions(module, service_methods);
}
