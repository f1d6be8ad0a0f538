/* A board's replier served without the interpreter: ROS's requests go to the board from the
 * receive thread, and the board's replies go back to ROS from it.
 *
 * Why: a service call through a board's replier cost two wake-ups of Python on the way (rclpy's
 * executor for the request, the loop for the reply) and the engine's delivery under its lock on
 * each: about 0.3 ms more per leg than eProsima's agent (bench/microros/service_roundtrip.py).
 *
 * How, as for a datareader (_reader_out.c, whose Reader this is, with a ServicePart): once rclpy's
 * executor has taken the service in, its on-new-request callback is pointed at on_new_message,
 * which marks the replier and writes the eventfd the receive thread polls. The thread then, under
 * the Receiver's mutex, takes each request (rcl_take_request, into the C message of the service's
 * request type), serializes it (rmw_serialize: the CDR bytes the Python path forwards), gives it
 * the next identity of this replier (the GUID Python gave it, the next sequence number) and sends
 * the DATA Python would send (identity, then the body) when Python has set the reader direct;
 * otherwise it hands identity and body to Python, which queues them as it queues a request. Either
 * way the request's rmw_request_id_t stays here, in a ring, until the board answers or the request
 * expires (the agent's request timeout, or never for an action's get_result, as Python has it).
 *
 * A reply the board writes (WRITE_DATA to the replier: the identity, then the body) is matched to
 * its request here, deserialized into the response type's C message (rmw_deserialize) and sent
 * (rcl_send_response): from the receive thread when the datagram is one this path takes, from
 * Python (send_reply) when the general path decoded it. A reply to an identity this ring does not
 * hold (a request rclpy's executor took before the callback was pointed here) is Python's: both
 * draw identities from the one counter here (replier_sequence), so they never collide.
 *
 * rcl and rmw are not linked: their functions are found in the libraries rclpy loaded. */
#include "_fastpath.h"

#define RCL_RET_OK 0
#define ENCAPSULATION 4
#define IDENTITY 24  /* SampleIdentity: GUID (16), sequence number (high int32, low uint32) */
#define MAX_TAKE_ROUND 64

typedef int (*take_request_fn)(const void *service, void *request_header, void *ros_request);
typedef int (*send_response_fn)(const void *service, void *request_header, void *ros_response);
typedef int (*serialize_fn)(const void *message, const void *type_support,
                            serialized_message_t *out);
typedef int (*deserialize_fn)(const serialized_message_t *in, const void *type_support,
                              void *message);

static set_event_callback_fn set_request_callback;
static take_request_fn take_request;
static send_response_fn send_response;
static serialize_fn serialize;
static deserialize_fn deserialize;
static reset_error_fn reset_error;

/* 1 once every function is found (and the readers' allocator, resolve_rcl_readers). */
int resolve_rcl_services(void) {
    if (set_request_callback == NULL) {
        take_request = (take_request_fn)loaded_symbol("librcl.so", "rcl_take_request");
        send_response = (send_response_fn)loaded_symbol("librcl.so", "rcl_send_response");
        serialize = (serialize_fn)loaded_symbol("librcl.so", "rmw_serialize");
        deserialize = (deserialize_fn)loaded_symbol("librcl.so", "rmw_deserialize");
        reset_error = (reset_error_fn)loaded_symbol("librcl.so", "rcutils_reset_error");
        set_event_callback_fn setter = (set_event_callback_fn)loaded_symbol(
            "librcl.so", "rcl_service_set_on_new_request_callback");
        if (take_request && send_response && serialize && deserialize && reset_error)
            set_request_callback = setter;
    }
    return set_request_callback != NULL;
}

/* ------------------------------------------------------------------------ the pending ring */

static PendingRequest *oldest(ServicePart *sp) {
    return &sp->pending[sp->head & (PENDING_REQUESTS - 1)];
}

/* Drop answered requests at the front, and those whose time is up; count the latter. */
static void expire(Receiver *self, ServicePart *sp, int64_t now) {
    while (sp->count) {
        PendingRequest *p = oldest(sp);
        if (p->sequence != 0 && !(p->deadline_ns && p->deadline_ns <= now)) break;
        if (p->sequence != 0) self->requests_expired++;
        p->sequence = 0;
        sp->head++;
        sp->count--;
    }
}

static void remember(Receiver *self, ServicePart *sp, uint64_t sequence, const uint64_t *header,
                     int64_t now) {
    expire(self, sp, now);
    if (sp->count == PENDING_REQUESTS) {  /* the board answers none: the oldest is forgotten */
        self->requests_expired++;
        oldest(sp)->sequence = 0;
        sp->head++;
        sp->count--;
    }
    PendingRequest *p = &sp->pending[(sp->head + sp->count) & (PENDING_REQUESTS - 1)];
    p->sequence = sequence;
    p->deadline_ns = sp->timeout_ns ? now + sp->timeout_ns : 0;
    memcpy(p->header, header, sizeof p->header);
    sp->count++;
}

static PendingRequest *pending_of(ServicePart *sp, uint64_t sequence) {
    for (unsigned i = 0; i < sp->count; i++) {
        PendingRequest *p = &sp->pending[(sp->head + i) & (PENDING_REQUESTS - 1)];
        if (p->sequence == sequence) return p;
    }
    return NULL;
}

static void put_identity(uint8_t *out, const ServicePart *sp, uint64_t sequence) {
    memcpy(out, sp->prefix, 16);
    uint32_t high = (uint32_t)(sequence >> 32), low = (uint32_t)sequence;
    for (int i = 0; i < 4; i++)
        out[16 + i] = (uint8_t)(high >> (8 * i)), out[20 + i] = (uint8_t)(low >> (8 * i));
}

static uint64_t identity_sequence(const uint8_t *identity) {
    uint32_t high = 0, low = 0;
    for (int i = 3; i >= 0; i--)
        high = high << 8 | identity[16 + i], low = low << 8 | identity[20 + i];
    return (uint64_t)high << 32 | low;
}

/* ---------------------------------------------------------------------------- requests out */

/* The request ``message`` as CDR in the take buffer (encapsulation first); its length, 0 when
 * it does not serialize. Fast CDR leaves alignment padding as it finds the buffer: zeroed first,
 * as xrce/agent/middleware/ros/_services.c does for Python's path, so both send the same bytes. */
static size_t serialize_request(Receiver *self, ServicePart *sp, void *message) {
    for (int attempt = 0; attempt < 2; attempt++) {
        size_t capacity = self->take_capacity;
        memset(self->take_buffer, 0, capacity);
        serialized_message_t out = {self->take_buffer, 0, capacity, take_allocator};
        int failed = serialize(message, sp->request_type, &out) != 0;
        self->take_buffer = out.buffer;  /* rmw grows it with the allocator when it must */
        self->take_capacity = out.buffer_capacity;
        if (failed) {
            reset_error();
            return 0;
        }
        if (out.buffer_capacity == capacity)  /* else grown: its new bytes were not zeroed */
            return out.buffer_length >= ENCAPSULATION ? out.buffer_length : 0;
    }
    return 0;
}

/* The receive thread, locked: every request waiting in the replier's service. */
void deliver_requests(Receiver *self, Reader *r) {
    ServicePart *sp = r->service;
    if (!ensure_take_buffer(self)) return;
    int taken;
    for (taken = 0; taken < MAX_TAKE_ROUND; taken++) {
        void *message = sp->create_request();
        if (message == NULL) break;
        uint64_t header[4] = {0};  /* rmw_request_id_t, 24 bytes */
        if (take_request(r->subscription, header, message) != RCL_RET_OK) {
            reset_error();  /* nothing left (rcl sets an error for "take failed" too) */
            sp->destroy_request(message);
            break;
        }
        size_t length = serialize_request(self, sp, message);
        sp->destroy_request(message);
        if (length == 0) {
            self->publish_errors++;  /* Python's path logs it; nothing can answer it */
            continue;
        }
        uint64_t sequence = ++sp->sequence;
        uint8_t identity[IDENTITY];
        put_identity(identity, sp, sequence);
        remember(self, sp, sequence, header, now_ns());
        if (send_direct(self, r, identity, IDENTITY, self->take_buffer, length)) continue;
        /* Python's: the identity and the body, as the middleware's request callback gives them */
        r->request_id = -1;  /* Python's until it has delivered what it holds */
        size_t body = length - ENCAPSULATION;
        uint8_t *sample = malloc(IDENTITY + body);
        if (sample != NULL) {
            memcpy(sample, identity, IDENTITY);
            memcpy(sample + IDENTITY, self->take_buffer + ENCAPSULATION, body);
        }
        if (sample == NULL || !handoff_append(self, r->token, sample, IDENTITY + body, NULL, 0))
            self->handoff_dropped++;  /* counted, as ReaderHandoff drops beyond its depth */
        free(sample);
        wake_python(self);
    }
    if (taken == MAX_TAKE_ROUND) {  /* more may wait: the next pass takes them */
        __atomic_store_n(&r->signalled, 1, __ATOMIC_RELEASE);
        uint64_t one = 1;
        ssize_t written = write(self->samples_fd, &one, sizeof one);
        (void)written;
    }
}

/* ------------------------------------------------------------------------------ replies in */

Reader *find_replier(Receiver *self, Client *c, uint16_t object_id) {
    for (Reader *r = self->readers; r; r = r->next)
        if (r->service && r->client == c && r->object_id == object_id) return r;
    return NULL;
}

/* ``sample`` (identity, then the reply's CDR body, ``length`` bytes in all) answers one of the
 * replier's requests: sent to its requester. 1 sent; 0 not a request of this ring (Python's);
 * -1 it does not deserialize or rcl refused it: the request is forgotten when ``final`` (Python
 * reports it), else kept for Python's try. The sample's bytes are as they came when it returns. */
int replier_reply(Receiver *self, Reader *r, uint8_t *sample, size_t length, int final) {
    ServicePart *sp = r->service;
    if (length < IDENTITY || memcmp(sample, sp->prefix, 16) != 0) return 0;
    expire(self, sp, now_ns());  /* a reply after the timeout finds nothing, as in Python */
    PendingRequest *p = pending_of(sp, identity_sequence(sample));
    if (p == NULL) return 0;
    void *message = sp->create_response();
    if (message == NULL) return -1;
    /* The body needs its encapsulation in front: the identity's last 4 bytes, read already. */
    uint8_t *cdr = sample + IDENTITY - ENCAPSULATION, saved[ENCAPSULATION];
    memcpy(saved, cdr, ENCAPSULATION);
    cdr[0] = 0x00, cdr[1] = 0x01, cdr[2] = 0x00, cdr[3] = 0x00;
    size_t cdr_length = length - IDENTITY + ENCAPSULATION;
    serialized_message_t in = {cdr, cdr_length, cdr_length, take_allocator};
    int sent = deserialize(&in, sp->response_type, message) == 0 &&
               send_response(r->subscription, p->header, message) == RCL_RET_OK;
    memcpy(cdr, saved, ENCAPSULATION);
    sp->destroy_response(message);
    if (!sent) {
        reset_error();
        if (!final) return -1;
    }
    p->sequence = 0;
    expire(self, sp, now_ns());
    return sent ? 1 : -1;
}

void free_service_part(Reader *r) {
    free(r->service);
    r->service = NULL;
}

/* ----------------------------------------------------------------------------- Python side */

static void *capsule_pointer(PyObject *capsule) {
    if (!PyCapsule_CheckExact(capsule)) {
        PyErr_SetString(PyExc_TypeError, "expected a capsule");
        return NULL;
    }
    return PyCapsule_GetPointer(capsule, PyCapsule_GetName(capsule));
}

/* add_replier(handle, object_id, service address, (request type support, create, destroy),
 * (response type support, create, destroy), identity prefix (16 bytes), last sequence, timeout s)
 * -> token (> 0), or 0 when the client is not registered: from now on the service's requests
 * reach the receive thread first (a Reader: set_reader_direct, remove_reader, reclaim_reader,
 * set_reader_client apply). Capsules as rclpy keeps them on a message class's metaclass. Timeout
 * 0: requests wait for their reply however long. */
PyObject *Receiver_add_replier(Receiver *self, PyObject *args) {
    long handle;
    int object_id;
    unsigned long long address, last_sequence;
    PyObject *request_capsules[3], *response_capsules[3];
    Py_buffer prefix = {0};
    double timeout_s;
    if (!PyArg_ParseTuple(args, "liK(OOO)(OOO)y*Kd", &handle, &object_id, &address,
                          &request_capsules[0], &request_capsules[1], &request_capsules[2],
                          &response_capsules[0], &response_capsules[1], &response_capsules[2],
                          &prefix, &last_sequence, &timeout_s))
        return NULL;
    int prefix_ok = prefix.len == 16;
    uint8_t prefix_bytes[16];
    if (prefix_ok) memcpy(prefix_bytes, prefix.buf, 16);
    PyBuffer_Release(&prefix);
    if (!prefix_ok) {
        PyErr_SetString(PyExc_ValueError, "the identity prefix is 16 bytes");
        return NULL;
    }
    PyObject *readers = resolve_rcl_readers();  /* the take buffer's allocator */
    int resolved = readers != NULL && PyObject_IsTrue(readers) && resolve_rcl_services();
    Py_XDECREF(readers);
    if (!resolved || !self->running) {
        PyErr_SetString(PyExc_RuntimeError,
                        "rcl's service calls not resolved, or no receive thread");
        return NULL;
    }
    void *pointers[6];
    for (int i = 0; i < 3; i++) {
        if ((pointers[i] = capsule_pointer(request_capsules[i])) == NULL ||
            (pointers[3 + i] = capsule_pointer(response_capsules[i])) == NULL)
            return NULL;
    }
    Reader *r = calloc(1, sizeof *r);
    ServicePart *sp = calloc(1, sizeof *sp);
    if (r == NULL || sp == NULL) {
        free(r);
        free(sp);
        return PyErr_NoMemory();
    }
    sp->request_type = pointers[0];
    sp->create_request = (void *(*)(void))pointers[1];
    sp->destroy_request = (void (*)(void *))pointers[2];
    sp->response_type = pointers[3];
    sp->create_response = (void *(*)(void))pointers[4];
    sp->destroy_response = (void (*)(void *))pointers[5];
    memcpy(sp->prefix, prefix_bytes, 16);
    sp->sequence = last_sequence;
    sp->timeout_ns = timeout_s > 0 ? (int64_t)(timeout_s * 1e9) : 0;
    r->service = sp;
    long token = link_reader(self, r, handle, object_id, address, set_request_callback);
    if (token <= 0) {
        free(sp);
        free(r);
    }
    if (token < 0) {
        reset_error();
        PyErr_SetString(PyExc_RuntimeError, "rcl refused the service's callback");
        return NULL;
    }
    return PyLong_FromLong(token);
}

static Reader *replier_by_token(Receiver *self, long token) {
    for (Reader *r = self->readers; r; r = r->next)
        if (r->token == token && r->service) return r;
    return NULL;
}

/* send_reply(token, sample) -> 1 sent, 0 not a request C holds (the middleware's), -1 failed
 * (forgotten): ``sample`` is the identity, then the reply's CDR body, as the board wrote it. */
PyObject *Receiver_send_reply(Receiver *self, PyObject *args) {
    long token;
    Py_buffer sample = {0};
    if (!PyArg_ParseTuple(args, "ly*", &token, &sample)) return NULL;
    /* replier_reply writes the encapsulation into the sample: a copy of Python's bytes */
    uint8_t *copy = malloc(sample.len ? (size_t)sample.len : 1);
    if (copy == NULL) {
        PyBuffer_Release(&sample);
        return PyErr_NoMemory();
    }
    memcpy(copy, sample.buf, (size_t)sample.len);
    size_t length = (size_t)sample.len;
    PyBuffer_Release(&sample);
    int result = 0;
    Py_BEGIN_ALLOW_THREADS
    pthread_mutex_lock(&self->mutex);
    Reader *r = replier_by_token(self, token);
    if (r != NULL) result = replier_reply(self, r, copy, length, 1);  /* Python counts it */
    pthread_mutex_unlock(&self->mutex);
    Py_END_ALLOW_THREADS
    free(copy);
    return PyLong_FromLong(result);
}

/* replier_sequence(token) -> the replier's next identity sequence number, taken now (for a
 * request rclpy's executor delivered to Python), or None once it is removed. */
PyObject *Receiver_replier_sequence(Receiver *self, PyObject *arg) {
    long token = PyLong_AsLong(arg);
    if (token == -1 && PyErr_Occurred()) return NULL;
    unsigned long long sequence = 0;
    pthread_mutex_lock(&self->mutex);
    Reader *r = replier_by_token(self, token);
    if (r != NULL) sequence = ++r->service->sequence;
    pthread_mutex_unlock(&self->mutex);
    if (r == NULL) Py_RETURN_NONE;
    return PyLong_FromUnsignedLongLong(sequence);
}

/* take_expired() -> requests the boards did not answer in time (or were pushed out of a full
 * ring), expired up to now, since the last call. */
PyObject *Receiver_take_expired(Receiver *self, PyObject *unused) {
    (void)unused;
    int64_t now = now_ns();
    pthread_mutex_lock(&self->mutex);
    for (Reader *r = self->readers; r; r = r->next)
        if (r->service) expire(self, r->service, now);
    unsigned long long expired = self->requests_expired;
    self->requests_expired = 0;
    pthread_mutex_unlock(&self->mutex);
    return PyLong_FromUnsignedLongLong(expired);
}
