/* Type supports for message and service types the agent knows only by their DDS name.
 *
 * Why: an XRCE client names its types (PX4: "px4_msgs::msg::dds_::SensorCombined_") and eProsima's
 * agent moves their CDR bytes without knowing anything else about them. rclpy needs a C type
 * support for every publisher, subscription, client and service; the agent publishes and takes
 * serialized bytes, so all the RMW needs from that support is the type's DDS name, and for
 * services (whose requests and replies rmw serializes itself) callbacks that copy the bytes as
 * they are. Here such a support is made from the name alone: what rosidl_typesupport_fastrtps_c
 * generates (namespace "pkg::msg", name "T": rmw_fastrtps names the DDS type
 * "pkg::msg::dds_::T_"), an introspection description with no field (rmw_fastrtps registers a
 * type object from it; on Fast DDS 2 only, see named_message_type) and an unset type hash with
 * a type description without fields (rcl's node type cache wants one). The structures are
 * ROS's own (_named_types.h); nothing of ROS is linked.
 *
 * A service's C message is a byte string (named_message_t): rmw's serialize callback writes it
 * as it is after the encapsulation, its deserialize callback keeps what follows the
 * encapsulation. Fast CDR's Cdr is reached through three exported member functions
 * (serialize_array, get_buffer_pointer, get_current_position: Itanium ABI, `this` first); the
 * end of its buffer, which no exported function gives, is read from its iterators (see
 * cdr_end). Only rmw_fastrtps_cpp is served: an RMW that serializes from the introspection
 * description (rmw_cyclonedds_cpp) would send no field at all, so resolve() names the reason
 * instead.
 *
 * Types are made once per name and never freed (rmw keeps pointers into them), at most
 * NAMED_TYPES_MAX in a process: a client inventing names gets an error past it.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include <dlfcn.h>
#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "_named_types.h"
#include "_rostypes.h"

#define NAMED_TYPES_MAX 1024
#define ENCAPSULATION 4

/* -------------------------------------------------------------------- a message known by name */

typedef struct { uint8_t *data; size_t length; } named_message_t;  /* CDR after the encapsulation */

/* pkg, kind, T -> "pkg::kind" (fastrtps), "pkg__kind" (introspection), "T", "pkg/kind/T" */
typedef struct { char *dds_namespace, *introspection_namespace, *name, *description_name; } names_t;

typedef struct {
    message_ts_t dispatch, fastrtps, introspection;  /* dispatch first: the handle rclpy holds */
    bool described;  /* whether the introspection (a struct without fields) is given out */
    fastrtps_callbacks_t callbacks;
    introspection_members_t members;
    type_description_t description;
    names_t names;
} named_type_t;

typedef struct {
    service_ts_t dispatch, fastrtps, introspection;
    bool described;
    fastrtps_service_callbacks_t callbacks;
    introspection_service_members_t members;
    named_type_t *request, *response;
    type_description_t description;
    names_t names;
} named_service_t;

_Static_assert(offsetof(named_type_t, fastrtps) == sizeof(message_ts_t) &&
               offsetof(named_type_t, introspection) == 2 * sizeof(message_ts_t) &&
               offsetof(named_type_t, described) == 3 * sizeof(message_ts_t),
               "a type's handles, then described (handle_for)");
_Static_assert(offsetof(named_service_t, fastrtps) == sizeof(service_ts_t) &&
               offsetof(named_service_t, introspection) == 2 * sizeof(service_ts_t) &&
               offsetof(named_service_t, described) == 3 * sizeof(service_ts_t),
               "a service's handles, then described (handle_for)");

static const type_hash_t unset_hash;  /* all zeros: ROSIDL_TYPE_HASH_VERSION_UNSET */
static const ros_sequence_t no_sources;
static int named_types_made;

static const char *fastrtps_identifier = "rosidl_typesupport_fastrtps_c";
static const char *introspection_identifier = "rosidl_typesupport_introspection_c";
static const char *dispatch_identifier = "rosidl_typesupport_c";

typedef void *(*cdr_serialize_array_fn)(void *cdr, const char *data, size_t length);
typedef char *(*cdr_position_fn)(void *cdr);
static cdr_serialize_array_fn cdr_serialize_array;
static cdr_position_fn cdr_buffer_pointer, cdr_current_position;

/* The identifiers rmw compares by address too (rmw_fastrtps_shared_cpp's register_type_object
 * tells the C introspection from the C++ one by pointer): the libraries' own, once rmw loaded
 * them. */
static const char *loaded_identifier(const char *library, const char *symbol, const char *fallback) {
    void *handle = dlopen(library, RTLD_NOW | RTLD_NOLOAD);
    if (handle == NULL) return fallback;
    const char *const *found = (const char *const *)dlsym(handle, symbol);
    dlclose(handle);
    return found != NULL && *found != NULL ? *found : fallback;
}

static const char *resolve(void) {
    static bool done;
    typedef const char *(*identifier_fn)(void);
    identifier_fn rmw_identifier = (identifier_fn)xrce_rcl_symbol("rmw_get_implementation_identifier");
    if (rmw_identifier == NULL) return "rmw is not loaded";
    const char *rmw = rmw_identifier();
    if (rmw == NULL || strcmp(rmw, "rmw_fastrtps_cpp") != 0)
        return "only rmw_fastrtps_cpp can carry a type known by name (its bytes as they are)";
    if (done) return NULL;
    void *fastcdr = dlopen("libfastcdr.so.2", RTLD_NOW | RTLD_NOLOAD);
    if (fastcdr == NULL) return "Fast CDR 2 (libfastcdr.so.2) is not loaded";
    cdr_serialize_array = (cdr_serialize_array_fn)dlsym(fastcdr, "_ZN8eprosima7fastcdr3Cdr15serialize_arrayEPKcm");
    cdr_buffer_pointer = (cdr_position_fn)dlsym(fastcdr, "_ZN8eprosima7fastcdr3Cdr18get_buffer_pointerEv");
    cdr_current_position = (cdr_position_fn)dlsym(fastcdr, "_ZN8eprosima7fastcdr3Cdr20get_current_positionEv");
    dlclose(fastcdr);  /* NOLOAD took a reference; rmw holds its own */
    if (!cdr_serialize_array || !cdr_buffer_pointer || !cdr_current_position)
        return "Fast CDR 2 lacks Cdr::serialize_array, get_buffer_pointer or get_current_position";
    fastrtps_identifier = loaded_identifier("librosidl_typesupport_fastrtps_c.so",
                                            "rosidl_typesupport_fastrtps_c__identifier",
                                            fastrtps_identifier);
    introspection_identifier = loaded_identifier("librosidl_typesupport_introspection_c.so",
                                                 "rosidl_typesupport_introspection_c__identifier",
                                                 introspection_identifier);
    dispatch_identifier = loaded_identifier("librosidl_typesupport_c.so",
                                            "rosidl_typesupport_c__typesupport_identifier",
                                            dispatch_identifier);
    done = true;
    return NULL;
}

/* The end of the buffer a Cdr works on. Fast CDR 2 keeps three iterators one after the other
 * (offset_, origin_, end_), each {buffer, position}: found in the object as three pairs sharing
 * the buffer pointer, the first at the current position. Its place is remembered and checked
 * again on every use; NULL where it is not found (then the callback fails as a short buffer
 * does, never reading past it). */
#define CDR_WORDS 64
static int cdr_iterators = -1;

static bool iterators_at(char *const *words, int at, const char *buffer, const char *position) {
    return words[at] == buffer && words[at + 1] == position && words[at + 2] == buffer &&
           words[at + 4] == buffer && words[at + 5] >= position;
}

static const char *cdr_end(void *cdr) {
    char *const *words = (char *const *)cdr;
    const char *buffer = cdr_buffer_pointer(cdr), *position = cdr_current_position(cdr);
    if (buffer == NULL || position == NULL) return NULL;
    if (cdr_iterators >= 0 && iterators_at(words, cdr_iterators, buffer, position))
        return words[cdr_iterators + 5];
    for (int at = 0; at + 5 < CDR_WORDS; at++) {
        if (iterators_at(words, at, buffer, position)) {
            cdr_iterators = at;
            return words[at + 5];
        }
    }
    return NULL;
}

static bool named_serialize(const void *message, void *cdr) {
    const named_message_t *named = message;
    const char *end = cdr_end(cdr);
    if (end == NULL || (size_t)(end - cdr_current_position(cdr)) < named->length) return false;
    if (named->length) cdr_serialize_array(cdr, (const char *)named->data, named->length);
    return true;
}

static bool named_deserialize(void *cdr, void *message) {
    named_message_t *named = message;
    const char *end = cdr_end(cdr), *position = cdr_current_position(cdr);
    if (end == NULL) return false;
    size_t length = (size_t)(end - position);
    uint8_t *data = malloc(length ? length : 1);
    if (data == NULL) return false;
    memcpy(data, position, length);
    free(named->data);
    named->data = data;
    named->length = length;
    return true;
}

static uint32_t named_serialized_size(const void *message) {
    return (uint32_t)((const named_message_t *)message)->length;
}

static size_t named_max_serialized_size(char *bounds_info) {
    *bounds_info = FASTRTPS_UNBOUNDED_TYPE;
    return 0;
}

static void no_init(void *message, int initialization) {
    (void)initialization;
    memset(message, 0, sizeof(named_message_t));
}

static void no_fini(void *message) {
    named_message_t *named = message;
    free(named->data);
    named->data = NULL;
    named->length = 0;
}

/* Kilted's rmw_fastrtps asks a type for its introspection to announce XTypes type information,
 * and where there is none (types without a description here) leaves its "Type support not from
 * this implementation" error set although the endpoint is made; Fast DDS 3 then tells rmw of the
 * new endpoint on the same thread, and rmw_dds_common, finding no type hash in its USER_DATA,
 * sets "user_data argument is null" over it: rcutils prints both as an error overwritten, for
 * every endpoint. Those two errors, and only they, are cleared whenever rmw calls into a type
 * known by name (its type hash is asked for between the two). */
typedef struct { char str[1024]; } error_string_t;  /* rcutils_error_string_t */
static const char *const stale_errors[] = {"Type support not from this implementation",
                                           "user_data argument is null"};

static void clear_stale_error(void) {
    static bool (*is_set)(void);
    static error_string_t (*get)(void);
    static reset_error_fn reset;
    if (is_set == NULL || get == NULL || reset == NULL) {
        is_set = (bool (*)(void))xrce_rcl_symbol("rcutils_error_is_set");
        get = (error_string_t (*)(void))xrce_rcl_symbol("rcutils_get_error_string");
        reset = (reset_error_fn)xrce_rcl_symbol("rcutils_reset_error");
        if (is_set == NULL || get == NULL || reset == NULL) return;
    }
    if (!is_set()) return;
    error_string_t error = get();
    for (size_t i = 0; i < sizeof stale_errors / sizeof *stale_errors; i++) {
        if (strncmp(error.str, stale_errors[i], strlen(stale_errors[i])) == 0) {
            reset();
            return;
        }
    }
}

/* A type's (or service's) three handles lie one after the other, dispatch first, then whether
 * it is described: from any of them, the first, and the one rmw asks for by identifier. */
static const char *first_handle(const void *handle, size_t size) {
    const char *identifier = *(const char *const *)handle;
    return (const char *)handle - (identifier == fastrtps_identifier ? size :
                                   identifier == introspection_identifier ? 2 * size : 0);
}

static const void *handle_for(const void *handle, size_t size, const char *identifier) {
    clear_stale_error();
    const char *first = first_handle(handle, size);
    if (strcmp(identifier, fastrtps_identifier) == 0) return first + size;
    if (*(const bool *)(first + 3 * size) && strcmp(identifier, introspection_identifier) == 0)
        return first + 2 * size;
    return NULL;
}

/* The functions rmw calls on a message's (service's) handles: which handle for an identifier,
 * the unset hash, the description without fields, no sources. */
#define HANDLE_FUNCTIONS(prefix, ts_t, owner_t)                                                  \
    static const ts_t *prefix##_handle(const ts_t *handle, const char *identifier) {             \
        return handle_for(handle, sizeof *handle, identifier);                                   \
    }                                                                                            \
    static const type_hash_t *prefix##_hash(const ts_t *handle) {                                \
        (void)handle;                                                                            \
        clear_stale_error();                                                                     \
        return &unset_hash;                                                                      \
    }                                                                                            \
    static const type_description_t *prefix##_description(const ts_t *handle) {                 \
        return &((const owner_t *)first_handle(handle, sizeof *handle))->description;            \
    }                                                                                            \
    static const ros_sequence_t *prefix##_sources(const ts_t *handle) {                          \
        (void)handle;                                                                            \
        return &no_sources;                                                                      \
    }

HANDLE_FUNCTIONS(message, message_ts_t, named_type_t)
HANDLE_FUNCTIONS(service, service_ts_t, named_service_t)

static char *joined(const char *a, const char *b, const char *c) {
    size_t length = strlen(a) + strlen(b) + strlen(c) + 1;
    char *out = malloc(length);
    if (out != NULL) snprintf(out, length, "%s%s%s", a, b, c);
    return out;
}

static void names_free(names_t *names) {
    free(names->dds_namespace);
    free(names->introspection_namespace);
    free(names->name);
    free(names->description_name);
}

static bool names_make(names_t *names, const char *package, const char *kind, const char *name) {
    names->dds_namespace = joined(package, "::", kind);
    names->introspection_namespace = joined(package, "__", kind);
    names->name = joined(name, "", "");
    char *kind_slash = joined("/", kind, "/");
    names->description_name = kind_slash ? joined(package, kind_slash, name) : NULL;
    free(kind_slash);
    if (names->dds_namespace && names->introspection_namespace && names->name &&
        names->description_name)
        return true;
    names_free(names);
    return false;
}

static void describe(type_description_t *description, char *name) {
    memset(description, 0, sizeof *description);
    description->type.type_name.data = name;
    description->type.type_name.size = strlen(name);
    description->type.type_name.capacity = description->type.type_name.size + 1;
}

static void message_ts_init(message_ts_t *ts, const char *identifier, const void *data) {
    ts->identifier = identifier;
    ts->data = data;
    ts->func = message_handle;
    ts->get_type_hash = message_hash;
    ts->get_type_description = message_description;
    ts->get_type_description_sources = message_sources;
}

/* package "px4_msgs", kind "msg" or "srv", name "SensorCombined" or "VehicleCommand_Request". */
static named_type_t *named_type_new(const char *package, const char *kind, const char *name,
                                    bool described) {
    named_type_t *type = calloc(1, sizeof *type);
    if (type == NULL) return NULL;
    type->described = described;
    if (!names_make(&type->names, package, kind, name)) {
        free(type);
        return NULL;
    }
    type->callbacks = (fastrtps_callbacks_t){
        type->names.dds_namespace, type->names.name, named_serialize, named_deserialize,
        named_serialized_size, named_max_serialized_size, NULL};
    type->members = (introspection_members_t){
        type->names.introspection_namespace, type->names.name, 0, sizeof(named_message_t), false, NULL,
        no_init, no_fini};
    describe(&type->description, type->names.description_name);
    message_ts_init(&type->dispatch, dispatch_identifier, NULL);
    message_ts_init(&type->fastrtps, fastrtps_identifier, &type->callbacks);
    message_ts_init(&type->introspection, introspection_identifier, &type->members);
    return type;
}

/* Why ``types`` more types cannot be made (a str), or NULL when they can. */
static PyObject *refusal(int types) {
    const char *why = resolve();
    if (why != NULL) return PyUnicode_FromString(why);
    if (named_types_made + types > NAMED_TYPES_MAX)
        return PyUnicode_FromFormat("%d types known by name already", NAMED_TYPES_MAX);
    return NULL;
}

/* named_message_type(package, kind, name, described) -> the capsule of message type
 * pkg/kind/name's support (kind "msg", or "action" for an action's parts), or a str saying why
 * there is none (another RMW, Fast CDR not loaded, too many types). ``described``: whether it
 * gives rmw an introspection description (a struct without fields), which Jazzy's rmw_fastrtps
 * needs to create an endpoint; Kilted's makes the endpoint's XTypes type information from it,
 * whose identifier would differ from the real type's and keep the endpoints apart, and without it
 * announces none: DDS then matches by type name, as before XTypes. */
static PyObject *named_message_type(PyObject *module, PyObject *args) {
    (void)module;
    const char *package, *kind, *name;
    int described;
    if (!PyArg_ParseTuple(args, "sssp", &package, &kind, &name, &described)) return NULL;
    PyObject *refused = refusal(1);
    if (refused != NULL) return refused;
    named_type_t *type = named_type_new(package, kind, name, described);
    if (type == NULL) return PyErr_NoMemory();
    named_types_made++;
    return PyCapsule_New(&type->dispatch, NULL, NULL);
}

/* ------------------------------------------------------------------ a service known by name */

static void service_ts_init(service_ts_t *ts, const char *identifier, const void *data,
                            const named_service_t *service) {
    ts->identifier = identifier;
    ts->data = data;
    ts->func = service_handle;
    ts->request = &service->request->dispatch;
    ts->response = &service->response->dispatch;
    ts->event = NULL;
    ts->get_type_hash = service_hash;
    ts->get_type_description = service_description;
    ts->get_type_description_sources = service_sources;
}

/* named_service_type(package, kind, name, described) -> (service, request, response) type
 * support capsules of service pkg/kind/name (kind "srv", or "action" for an action's SendGoal and
 * GetResult), or a str saying why there are none; ``described`` as for named_message_type. */
static PyObject *named_service_type(PyObject *module, PyObject *args) {
    (void)module;
    const char *package, *kind, *name;
    int described;
    if (!PyArg_ParseTuple(args, "sssp", &package, &kind, &name, &described)) return NULL;
    PyObject *refused = refusal(3);
    if (refused != NULL) return refused;
    named_service_t *service = calloc(1, sizeof *service);
    char *request_name = joined(name, "_Request", ""), *response_name = joined(name, "_Response", "");
    if (service == NULL || request_name == NULL || response_name == NULL) goto no_memory;
    service->described = described;
    service->request = named_type_new(package, kind, request_name, described);
    service->response = named_type_new(package, kind, response_name, described);
    if (!service->request || !service->response ||
        !names_make(&service->names, package, kind, name))
        goto no_memory;  /* what was made is left: a few bytes, once, when memory ran out */
    free(request_name);
    free(response_name);
    service->callbacks = (fastrtps_service_callbacks_t){
        service->names.dds_namespace, service->names.name, &service->request->fastrtps,
        &service->response->fastrtps};
    service->members = (introspection_service_members_t){
        service->names.introspection_namespace, service->names.name, &service->request->members,
        &service->response->members, NULL};
    describe(&service->description, service->names.description_name);
    service_ts_init(&service->dispatch, dispatch_identifier, NULL, service);
    service_ts_init(&service->fastrtps, fastrtps_identifier, &service->callbacks, service);
    service_ts_init(&service->introspection, introspection_identifier, &service->members, service);
    named_types_made += 3;
    return Py_BuildValue("(NNN)", PyCapsule_New(&service->dispatch, NULL, NULL),
                         PyCapsule_New(&service->request->dispatch, NULL, NULL),
                         PyCapsule_New(&service->response->dispatch, NULL, NULL));
no_memory:
    free(request_name);
    free(response_name);
    return PyErr_NoMemory();
}

/* ----------------------------------------- a service's C message <-> rclpy, as CDR bytes */

static void *named_create(void) {
    return calloc(1, sizeof(named_message_t));
}

static void named_destroy(void *message) {
    if (message == NULL) return;
    no_fini(message);
    free(message);
}

/* Taken (a request for a replier, a reply for a requester): its bytes after the encapsulation. */
static PyObject *named_to_py(void *message) {
    const named_message_t *named = message;
    return PyBytes_FromStringAndSize((const char *)named->data, (Py_ssize_t)named->length);
}

/* Sent: an object whose ``cdr`` is the sample with its encapsulation (raw_types.RawReply). */
static bool named_from_py(PyObject *object, void *message) {
    PyObject *cdr = PyObject_GetAttrString(object, "cdr");
    if (cdr == NULL) return false;
    Py_buffer view;
    bool done = false;
    if (PyObject_GetBuffer(cdr, &view, PyBUF_SIMPLE) == 0) {
        if (view.len < ENCAPSULATION) {
            PyErr_SetString(PyExc_ValueError, "a sample without its encapsulation");
        } else {
            size_t length = (size_t)view.len - ENCAPSULATION;
            uint8_t *data = malloc(length ? length : 1);
            if (data == NULL) {
                PyErr_NoMemory();
            } else {
                memcpy(data, (const char *)view.buf + ENCAPSULATION, length);
                named_message_t *named = message;
                free(named->data);
                named->data = data;
                named->length = length;
                done = true;
            }
        }
        PyBuffer_Release(&view);
    }
    Py_DECREF(cdr);
    return done;
}

/* named_conversions() -> (create, destroy, to_py, from_py) capsules of a service's messages. */
static PyObject *named_conversions(PyObject *module, PyObject *unused) {
    (void)module;
    (void)unused;
    return Py_BuildValue("(NNNN)", PyCapsule_New((void *)named_create, NULL, NULL),
                         PyCapsule_New((void *)named_destroy, NULL, NULL),
                         PyCapsule_New((void *)named_to_py, NULL, NULL),
                         PyCapsule_New((void *)named_from_py, NULL, NULL));
}

static PyMethodDef named_type_methods[] = {
    {"named_message_type", named_message_type, METH_VARARGS, NULL},
    {"named_service_type", named_service_type, METH_VARARGS, NULL},
    {"named_conversions", named_conversions, METH_NOARGS, NULL},
    {NULL},
};

int xrce_named_types_add(PyObject *module) {
    return PyModule_AddFunctions(module, named_type_methods);
}
