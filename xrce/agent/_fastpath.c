/* Optional compiled receive path of the UDP link: best-effort WRITE_DATA straight into rcl.
 *
 * Why it exists: at a robot's rates the agent's cost is wake-ups of the Python loop, and at high
 * rates the Python work per datagram; both were measured at their floors in Python
 * (bench/agent_cost.py). Here one thread without the GIL owns the UDP socket's reads. A datagram
 * whose every submessage is a WRITE_DATA (FORMAT_DATA) to a datawriter Python registered, on a
 * best-effort stream Python registered, is published with rcl_publish_serialized_message from this
 * thread. Every other datagram (reliable streams, fragments, control, unknown clients, anything
 * malformed) is queued unchanged for the Python link, which takes the queue when an eventfd wakes
 * its loop: Python keeps every decision it makes today. xrce/agent/fastpath.py is the Python side.
 *
 * Ownership: Python decides what is fast (clients, streams, writers and their rcl publishers) and
 * removes a writer before it destroys the publisher; the mutex makes that removal wait for a publish
 * in progress. This thread owns the input sequence number of every registered stream: Python asks
 * (stream_accept) for the datagrams of those streams it handles. To keep those decisions in arrival
 * order, nothing is published here while Python still holds datagrams it was handed ("unfinished").
 * Counters accumulate here and Python folds them into its own (fold).
 *
 * rcl is not linked: the function is looked up in the librcl rclpy already loaded, so the module
 * builds with no ROS headers, and without rclpy loaded the Python path simply stays in charge.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include <arpa/inet.h>
#include <dlfcn.h>
#include <errno.h>
#include <netinet/in.h>
#include <poll.h>
#include <pthread.h>
#include <stdint.h>
#include <string.h>
#include <sys/eventfd.h>
#include <sys/mman.h>
#include <sys/socket.h>
#include <time.h>
#include <unistd.h>

#define BATCH 64            /* datagrams per recvmmsg */
#define MAX_DATAGRAM 65536  /* UDP's limit: nothing is ever truncated */
#define QUEUE_BYTES_LIMIT (8u << 20)  /* datagrams waiting for Python; beyond, dropped and counted */
#define WRITE_DATA 0x07
#define FORMAT_MASK 0x0E
#define FORMAT_DATA 0x00

/* rcutils_allocator_t and rcutils_uint8_array_t (rcl_serialized_message_t), as rcutils declares
 * them; rmw reads only buffer and buffer_length of a message it publishes. */
typedef struct {
    void *allocate, *deallocate, *reallocate, *zero_allocate, *state;
} rcutils_allocator_t;
typedef struct {
    uint8_t *buffer;
    size_t buffer_length;
    size_t buffer_capacity;
    rcutils_allocator_t allocator;
} serialized_message_t;
typedef int (*publish_serialized_fn)(const void *publisher, const serialized_message_t *message,
                                     void *allocation);
static publish_serialized_fn rcl_publish_serialized;

typedef struct Writer {
    struct Writer *next;
    uint16_t object_id;
    const void *publisher;  /* rcl_publisher_t *, valid while registered */
    uint64_t samples, sample_bytes;
} Writer;

typedef struct Stream {
    struct Stream *next;
    uint8_t stream_id;
    uint16_t last_seq;  /* the last accepted sequence number (XRCE-WIRE.md §1) */
} Stream;

typedef struct Client {
    struct Client *next;
    long handle;
    int enabled;  /* Python clears it while the client needs its attention (dead, parked, ...) */
    uint8_t session_id;
    uint8_t key[4];                /* sessions with the key in the header (id < 0x80) */
    struct sockaddr_storage addr;  /* sessions without: identified by the source address */
    socklen_t addr_len;
    Stream *streams;
    Writer *writers;
    uint64_t messages, bytes;
    int64_t last_seen_ns;  /* CLOCK_MONOTONIC, time.monotonic()'s clock; 0: nothing new */
} Client;

typedef struct Pending {
    struct Pending *next;
    struct sockaddr_storage addr;
    socklen_t addr_len;
    size_t length;
    uint8_t data[];
} Pending;

typedef struct {
    PyObject_HEAD
    int sock, notify_fd, stop_fd;
    pthread_t thread;
    int running;
    pthread_mutex_t mutex;
    Client *clients;
    long next_handle;
    int enabled;
    Pending *head, *tail;
    size_t queued, queued_bytes, unfinished;  /* unfinished: queued + taken, not yet finished */
    int notified;
    /* Agent-wide counters since the last fold. */
    uint64_t messages, bytes, samples, stale, publish_errors, queue_drops;
    /* BATCH * 64 KB mapped lazily: only the pages datagrams touch become resident. */
    uint8_t (*buffers)[MAX_DATAGRAM];
} Receiver;

static int64_t now_ns(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (int64_t)ts.tv_sec * 1000000000 + ts.tv_nsec;
}

/* 16-bit serial-number order (xrce/streams.py seq_less). */
static int seq_less(uint16_t a, uint16_t b) {
    if (a == b) return 0;
    return (a < b && b - a < 0x8000) || (a > b && a - b > 0x8000);
}

static int same_address(const struct sockaddr_storage *a, const struct sockaddr_storage *b) {
    if (a->ss_family != b->ss_family) return 0;
    if (a->ss_family == AF_INET) {
        const struct sockaddr_in *x = (const void *)a, *y = (const void *)b;
        return x->sin_port == y->sin_port && x->sin_addr.s_addr == y->sin_addr.s_addr;
    }
    if (a->ss_family == AF_INET6) {
        const struct sockaddr_in6 *x = (const void *)a, *y = (const void *)b;
        return x->sin6_port == y->sin6_port && x->sin6_scope_id == y->sin6_scope_id &&
               memcmp(&x->sin6_addr, &y->sin6_addr, sizeof x->sin6_addr) == 0;
    }
    return 0;
}

static Client *find_client(Receiver *self, const uint8_t *data, const struct sockaddr_storage *from) {
    for (Client *c = self->clients; c; c = c->next) {
        if (c->session_id != data[0]) continue;
        if (data[0] < 0x80 ? memcmp(c->key, data + 4, 4) == 0 : same_address(&c->addr, from))
            return c;
    }
    return NULL;
}

static Writer *find_writer(Client *c, uint16_t object_id) {
    for (Writer *w = c->writers; w; w = w->next)
        if (w->object_id == object_id) return w;
    return NULL;
}

static Stream *find_stream(Client *c, uint8_t stream_id) {
    for (Stream *s = c->streams; s; s = s->next)
        if (s->stream_id == stream_id) return s;
    return NULL;
}

/* Publish the datagram here if all of it is fast; 0 when Python must have it. Called locked. */
static int try_fast(Receiver *self, uint8_t *data, size_t length, const struct sockaddr_storage *from) {
    if (!self->enabled || rcl_publish_serialized == NULL || length < 12) return 0;
    uint8_t session_id = data[0];
    if ((session_id & 0x7F) == 0 || data[1] == 0 || data[1] >= 0x80) return 0;
    Client *client = find_client(self, data, from);
    if (client == NULL || !client->enabled) return 0;
    Stream *stream = find_stream(client, data[1]);
    if (stream == NULL) return 0;
    /* Every submessage must be a WRITE_DATA to a registered writer, or Python takes it all:
     * the same walk as xrce/message.py iter_submessages, every length checked. */
    size_t pos = session_id < 0x80 ? 8 : 4, count = 0;
    while (length - pos >= 4) {
        size_t sub_length = data[pos + 2] | (data[pos + 3] << 8);
        size_t end = pos + 4 + sub_length;
        if (data[pos] != WRITE_DATA || (data[pos + 1] & FORMAT_MASK) != FORMAT_DATA ||
            sub_length < 4 || end > length ||
            find_writer(client, (uint16_t)(data[pos + 6] << 8 | data[pos + 7])) == NULL)
            return 0;
        count++;
        pos = (end + 3) & ~(size_t)3;
        if (pos > length) break;
    }
    if (count == 0 || self->unfinished) return 0;
    uint16_t seq = data[2] | (data[3] << 8);
    client->messages++;
    client->bytes += length;
    client->last_seen_ns = now_ns();
    self->messages++;
    self->bytes += length;
    if (!seq_less(stream->last_seq, seq)) {
        self->stale++;  /* older or repeated: a best-effort stream drops it */
        return 1;
    }
    stream->last_seq = seq;
    pos = session_id < 0x80 ? 8 : 4;
    while (count--) {
        size_t sub_length = data[pos + 2] | (data[pos + 3] << 8);
        Writer *writer = find_writer(client, (uint16_t)(data[pos + 6] << 8 | data[pos + 7]));
        /* ROS wants the CDR body behind its 4-byte encapsulation header (XRCE-WIRE.md §14);
         * the request and object ids in front of the sample are that space, already used. */
        uint8_t *body = data + pos + 4;
        body[0] = 0x00, body[1] = 0x01, body[2] = 0x00, body[3] = 0x00;
        serialized_message_t message = {body, sub_length, sub_length, {0}};
        self->samples++;
        writer->samples++;
        writer->sample_bytes += sub_length - 4;
        if (rcl_publish_serialized(writer->publisher, &message, NULL) != 0) {
            self->publish_errors++;  /* as in Python, a failed write ends the message */
            break;
        }
        pos = (pos + 4 + sub_length + 3) & ~(size_t)3;
    }
    return 1;
}

/* Hand a datagram to Python. Called locked; returns 1 if Python must be woken. */
static int queue_for_python(Receiver *self, const uint8_t *data, size_t length,
                            const struct sockaddr_storage *from, socklen_t from_len) {
    if (self->queued_bytes + length > QUEUE_BYTES_LIMIT) {
        self->queue_drops++;
        return 0;
    }
    Pending *item = malloc(sizeof(Pending) + length);
    if (item == NULL) {
        self->queue_drops++;
        return 0;
    }
    item->next = NULL;
    memcpy(&item->addr, from, from_len);
    item->addr_len = from_len;
    item->length = length;
    memcpy(item->data, data, length);
    if (self->tail) self->tail->next = item; else self->head = item;
    self->tail = item;
    self->queued++;
    self->queued_bytes += length;
    self->unfinished++;
    if (self->notified) return 0;
    self->notified = 1;
    return 1;
}

static void *receive_loop(void *arg) {
    Receiver *self = arg;
    static __thread struct mmsghdr messages[BATCH];
    static __thread struct iovec vectors[BATCH];
    static __thread struct sockaddr_storage sources[BATCH];
    struct pollfd fds[2] = {{self->sock, POLLIN, 0}, {self->stop_fd, POLLIN, 0}};
    for (;;) {
        if (poll(fds, 2, -1) < 0 && errno != EINTR) break;
        if (fds[1].revents) break;
        for (int i = 0; i < BATCH; i++) {
            vectors[i].iov_base = self->buffers[i];
            vectors[i].iov_len = MAX_DATAGRAM;
            memset(&messages[i].msg_hdr, 0, sizeof messages[i].msg_hdr);
            messages[i].msg_hdr.msg_iov = &vectors[i];
            messages[i].msg_hdr.msg_iovlen = 1;
            messages[i].msg_hdr.msg_name = &sources[i];
            messages[i].msg_hdr.msg_namelen = sizeof sources[i];
        }
        int count = recvmmsg(self->sock, messages, BATCH, MSG_DONTWAIT, NULL);
        if (count <= 0) continue;  /* EAGAIN, or an ICMP error of an earlier send: nothing lost */
        int wake = 0;
        pthread_mutex_lock(&self->mutex);
        for (int i = 0; i < count; i++) {
            size_t length = messages[i].msg_len;
            if (!try_fast(self, self->buffers[i], length, &sources[i]))
                wake |= queue_for_python(self, self->buffers[i], length, &sources[i],
                                         messages[i].msg_hdr.msg_namelen);
        }
        pthread_mutex_unlock(&self->mutex);
        if (wake) {
            uint64_t one = 1;
            if (write(self->notify_fd, &one, sizeof one) < 0) { /* the counter is already set */ }
        }
    }
    return NULL;
}

/* ----------------------------------------------------------------------------- Python side */

static PyObject *address_tuple(const struct sockaddr_storage *addr) {
    char text[INET6_ADDRSTRLEN];
    if (addr->ss_family == AF_INET) {
        const struct sockaddr_in *a = (const void *)addr;
        inet_ntop(AF_INET, &a->sin_addr, text, sizeof text);
        return Py_BuildValue("(si)", text, ntohs(a->sin_port));
    }
    const struct sockaddr_in6 *a = (const void *)addr;
    inet_ntop(AF_INET6, &a->sin6_addr, text, sizeof text);
    return Py_BuildValue("(siII)", text, ntohs(a->sin6_port), ntohl(a->sin6_flowinfo),
                         a->sin6_scope_id);
}

static int parse_address(PyObject *tuple, struct sockaddr_storage *out, socklen_t *len) {
    const char *host;
    int port;
    unsigned int flowinfo = 0, scope_id = 0;
    memset(out, 0, sizeof *out);
    if (!PyArg_ParseTuple(tuple, "si|II", &host, &port, &flowinfo, &scope_id)) return -1;
    struct sockaddr_in *v4 = (void *)out;
    struct sockaddr_in6 *v6 = (void *)out;
    if (inet_pton(AF_INET, host, &v4->sin_addr) == 1) {
        v4->sin_family = AF_INET;
        v4->sin_port = htons(port);
        *len = sizeof *v4;
        return 0;
    }
    if (inet_pton(AF_INET6, host, &v6->sin6_addr) == 1) {
        v6->sin6_family = AF_INET6;
        v6->sin6_port = htons(port);
        v6->sin6_flowinfo = htonl(flowinfo);
        v6->sin6_scope_id = scope_id;
        *len = sizeof *v6;
        return 0;
    }
    PyErr_Format(PyExc_ValueError, "not a numeric address: %s", host);
    return -1;
}

static Client *client_by_handle(Receiver *self, long handle) {
    for (Client *c = self->clients; c; c = c->next)
        if (c->handle == handle) return c;
    return NULL;
}

static void free_client(Client *c) {
    for (Writer *w = c->writers, *n; w; w = n) { n = w->next; free(w); }
    for (Stream *s = c->streams, *n; s; s = n) { n = s->next; free(s); }
    free(c);
}

static int Receiver_init(Receiver *self, PyObject *args, PyObject *kwargs) {
    static char *names[] = {"sock", NULL};
    if (!PyArg_ParseTupleAndKeywords(args, kwargs, "i", names, &self->sock)) return -1;
    self->notify_fd = eventfd(0, EFD_NONBLOCK | EFD_CLOEXEC);
    self->stop_fd = eventfd(0, EFD_NONBLOCK | EFD_CLOEXEC);
    if (self->notify_fd < 0 || self->stop_fd < 0) {
        PyErr_SetFromErrno(PyExc_OSError);
        return -1;
    }
    pthread_mutex_init(&self->mutex, NULL);
    self->enabled = 1;
    self->next_handle = 1;
    return 0;
}

static PyObject *Receiver_start(Receiver *self, PyObject *unused) {
    if (self->running) Py_RETURN_NONE;
    if (self->buffers == NULL) {
        void *map = mmap(NULL, (size_t)BATCH * MAX_DATAGRAM, PROT_READ | PROT_WRITE,
                         MAP_PRIVATE | MAP_ANONYMOUS, -1, 0);
        if (map == MAP_FAILED) return PyErr_SetFromErrno(PyExc_OSError);
        self->buffers = map;
    }
    int error = pthread_create(&self->thread, NULL, receive_loop, self);
    if (error) {
        errno = error;
        return PyErr_SetFromErrno(PyExc_OSError);
    }
    self->running = 1;
    Py_RETURN_NONE;
}

static void stop_thread(Receiver *self) {
    if (!self->running) return;
    uint64_t one = 1;
    if (write(self->stop_fd, &one, sizeof one) < 0) { /* already signalled */ }
    Py_BEGIN_ALLOW_THREADS
    pthread_join(self->thread, NULL);
    Py_END_ALLOW_THREADS
    self->running = 0;
}

static PyObject *Receiver_stop(Receiver *self, PyObject *unused) {
    stop_thread(self);
    Py_RETURN_NONE;
}

static void Receiver_dealloc(Receiver *self) {
    stop_thread(self);
    for (Client *c = self->clients, *n; c; c = n) { n = c->next; free_client(c); }
    for (Pending *p = self->head, *n; p; p = n) { n = p->next; free(p); }
    if (self->buffers) munmap(self->buffers, (size_t)BATCH * MAX_DATAGRAM);
    if (self->notify_fd > 0) close(self->notify_fd);
    if (self->stop_fd > 0) close(self->stop_fd);
    pthread_mutex_destroy(&self->mutex);
    Py_TYPE(self)->tp_free((PyObject *)self);
}

static PyObject *Receiver_take(Receiver *self, PyObject *unused) {
    uint64_t counter;
    if (read(self->notify_fd, &counter, sizeof counter) < 0) { /* not set: nothing new */ }
    pthread_mutex_lock(&self->mutex);
    Pending *items = self->head;
    self->head = self->tail = NULL;
    self->queued = self->queued_bytes = 0;
    self->notified = 0;
    pthread_mutex_unlock(&self->mutex);
    PyObject *list = PyList_New(0);
    for (Pending *p = items, *n; p; p = n) {
        n = p->next;
        PyObject *item = list ? Py_BuildValue("(y#N)", p->data, (Py_ssize_t)p->length,
                                              address_tuple(&p->addr)) : NULL;
        if (item == NULL || PyList_Append(list, item) < 0) Py_CLEAR(list);
        Py_XDECREF(item);
        free(p);
    }
    return list;
}

static PyObject *Receiver_finished(Receiver *self, PyObject *arg) {
    Py_ssize_t count = PyLong_AsSsize_t(arg);
    if (count < 0 && PyErr_Occurred()) return NULL;
    pthread_mutex_lock(&self->mutex);
    self->unfinished = (size_t)count > self->unfinished ? 0 : self->unfinished - count;
    pthread_mutex_unlock(&self->mutex);
    Py_RETURN_NONE;
}

static PyObject *Receiver_add_client(Receiver *self, PyObject *args) {
    int session_id;
    Py_buffer key = {0};
    PyObject *address;
    if (!PyArg_ParseTuple(args, "iy*O", &session_id, &key, &address)) return NULL;
    Client *c = calloc(1, sizeof *c);
    if (c == NULL) {
        PyBuffer_Release(&key);
        return PyErr_NoMemory();
    }
    c->session_id = (uint8_t)session_id;
    memcpy(c->key, key.buf, key.len < 4 ? key.len : 4);
    PyBuffer_Release(&key);
    if (session_id >= 0x80 && parse_address(address, &c->addr, &c->addr_len) < 0) {
        free(c);
        return NULL;
    }
    c->enabled = 1;
    pthread_mutex_lock(&self->mutex);
    c->handle = self->next_handle++;
    c->next = self->clients;
    self->clients = c;
    pthread_mutex_unlock(&self->mutex);
    return PyLong_FromLong(c->handle);
}

static PyObject *Receiver_remove_client(Receiver *self, PyObject *arg) {
    long handle = PyLong_AsLong(arg);
    if (handle == -1 && PyErr_Occurred()) return NULL;
    pthread_mutex_lock(&self->mutex);
    for (Client **link = &self->clients; *link; link = &(*link)->next) {
        if ((*link)->handle == handle) {
            Client *c = *link;
            *link = c->next;
            free_client(c);
            break;
        }
    }
    pthread_mutex_unlock(&self->mutex);
    Py_RETURN_NONE;
}

static PyObject *Receiver_set_client_enabled(Receiver *self, PyObject *args) {
    long handle;
    int enabled;
    if (!PyArg_ParseTuple(args, "lp", &handle, &enabled)) return NULL;
    pthread_mutex_lock(&self->mutex);
    Client *c = client_by_handle(self, handle);
    if (c) c->enabled = enabled;
    pthread_mutex_unlock(&self->mutex);
    Py_RETURN_NONE;
}

static PyObject *Receiver_set_enabled(Receiver *self, PyObject *arg) {
    int enabled = PyObject_IsTrue(arg);
    if (enabled < 0) return NULL;
    pthread_mutex_lock(&self->mutex);
    self->enabled = enabled;
    pthread_mutex_unlock(&self->mutex);
    Py_RETURN_NONE;
}

/* add_stream(handle, stream_id, last_seq): from now on the sequence number lives here. */
static PyObject *Receiver_add_stream(Receiver *self, PyObject *args) {
    long handle;
    int stream_id, last_seq;
    if (!PyArg_ParseTuple(args, "lii", &handle, &stream_id, &last_seq)) return NULL;
    pthread_mutex_lock(&self->mutex);
    Client *c = client_by_handle(self, handle);
    Stream *s = c ? find_stream(c, (uint8_t)stream_id) : NULL;
    if (c && s == NULL && (s = calloc(1, sizeof *s)) != NULL) {
        s->stream_id = (uint8_t)stream_id;
        s->next = c->streams;
        c->streams = s;
    }
    if (s) s->last_seq = (uint16_t)last_seq;
    pthread_mutex_unlock(&self->mutex);
    if (c && s == NULL) return PyErr_NoMemory();
    return PyBool_FromLong(s != NULL);
}

/* stream_accept(handle, stream_id, seq): the best-effort check for a datagram Python handles. */
static PyObject *Receiver_stream_accept(Receiver *self, PyObject *args) {
    long handle;
    int stream_id, seq;
    if (!PyArg_ParseTuple(args, "lii", &handle, &stream_id, &seq)) return NULL;
    int accepted = 0;
    pthread_mutex_lock(&self->mutex);
    Client *c = client_by_handle(self, handle);
    Stream *s = c ? find_stream(c, (uint8_t)stream_id) : NULL;
    if (s && seq_less(s->last_seq, (uint16_t)seq)) {
        s->last_seq = (uint16_t)seq;
        accepted = 1;
    }
    pthread_mutex_unlock(&self->mutex);
    return PyBool_FromLong(accepted);
}

static PyObject *Receiver_stream_seq(Receiver *self, PyObject *args) {
    long handle;
    int stream_id;
    if (!PyArg_ParseTuple(args, "li", &handle, &stream_id)) return NULL;
    long seq = -1;
    pthread_mutex_lock(&self->mutex);
    Client *c = client_by_handle(self, handle);
    Stream *s = c ? find_stream(c, (uint8_t)stream_id) : NULL;
    if (s) seq = s->last_seq;
    pthread_mutex_unlock(&self->mutex);
    if (seq < 0) Py_RETURN_NONE;
    return PyLong_FromLong(seq);
}

/* add_writer(handle, object_id, publisher_address): the address of an rcl_publisher_t that Python
 * keeps alive until remove_writer has returned. */
static PyObject *Receiver_add_writer(Receiver *self, PyObject *args) {
    long handle;
    int object_id;
    unsigned long long address;
    if (!PyArg_ParseTuple(args, "liK", &handle, &object_id, &address)) return NULL;
    if (address == 0) {
        PyErr_SetString(PyExc_ValueError, "null publisher");
        return NULL;
    }
    pthread_mutex_lock(&self->mutex);
    Client *c = client_by_handle(self, handle);
    Writer *w = c ? find_writer(c, (uint16_t)object_id) : NULL;
    if (c && w == NULL && (w = calloc(1, sizeof *w)) != NULL) {
        w->object_id = (uint16_t)object_id;
        w->next = c->writers;
        c->writers = w;
    }
    if (w) w->publisher = (const void *)(uintptr_t)address;
    pthread_mutex_unlock(&self->mutex);
    if (c && w == NULL) return PyErr_NoMemory();
    return PyBool_FromLong(w != NULL);
}

/* remove_writer(handle, object_id): returns (samples, bytes) not folded yet. Once it returns, this
 * thread holds no reference to the publisher (the mutex covers every publish). */
static PyObject *Receiver_remove_writer(Receiver *self, PyObject *args) {
    long handle;
    int object_id;
    if (!PyArg_ParseTuple(args, "li", &handle, &object_id)) return NULL;
    uint64_t samples = 0, bytes = 0;
    pthread_mutex_lock(&self->mutex);
    Client *c = client_by_handle(self, handle);
    for (Writer **link = c ? &c->writers : NULL; link && *link; link = &(*link)->next) {
        if ((*link)->object_id == (uint16_t)object_id) {
            Writer *w = *link;
            *link = w->next;
            samples = w->samples, bytes = w->sample_bytes;
            free(w);
            break;
        }
    }
    pthread_mutex_unlock(&self->mutex);
    return Py_BuildValue("(KK)", (unsigned long long)samples, (unsigned long long)bytes);
}

/* fold(): the counters since the previous fold, reset here:
 * ((messages, bytes, samples, stale, publish_errors, queue_drops),
 *  [(handle, messages, bytes, last_seen_ns)], [(handle, object_id, samples, bytes)]) */
static PyObject *Receiver_fold(Receiver *self, PyObject *unused) {
    PyObject *clients = PyList_New(0), *writers = PyList_New(0), *result = NULL;
    if (clients == NULL || writers == NULL) goto done;
    pthread_mutex_lock(&self->mutex);
    int failed = 0;
    for (Client *c = self->clients; c && !failed; c = c->next) {
        if (c->messages) {
            PyObject *row = Py_BuildValue("(lKKL)", c->handle, (unsigned long long)c->messages,
                                          (unsigned long long)c->bytes, (long long)c->last_seen_ns);
            failed = row == NULL || PyList_Append(clients, row) < 0;
            Py_XDECREF(row);
            c->messages = c->bytes = 0;
        }
        for (Writer *w = c->writers; w && !failed; w = w->next) {
            if (!w->samples) continue;
            PyObject *row = Py_BuildValue("(liKK)", c->handle, (int)w->object_id,
                                          (unsigned long long)w->samples,
                                          (unsigned long long)w->sample_bytes);
            failed = row == NULL || PyList_Append(writers, row) < 0;
            Py_XDECREF(row);
            w->samples = w->sample_bytes = 0;
        }
    }
    PyObject *totals = Py_BuildValue("(KKKKKK)", (unsigned long long)self->messages,
                                     (unsigned long long)self->bytes,
                                     (unsigned long long)self->samples,
                                     (unsigned long long)self->stale,
                                     (unsigned long long)self->publish_errors,
                                     (unsigned long long)self->queue_drops);
    self->messages = self->bytes = self->samples = self->stale = 0;
    self->publish_errors = self->queue_drops = 0;
    pthread_mutex_unlock(&self->mutex);
    if (!failed && totals) result = Py_BuildValue("(NOO)", totals, clients, writers);
    else Py_XDECREF(totals);
done:
    Py_XDECREF(clients);
    Py_XDECREF(writers);
    return result;
}

/* handle(data, address): run try_fast on one datagram as the thread would, for tests and fuzzing
 * without a socket; True if it was taken here, False if Python would have it. */
static PyObject *Receiver_handle(Receiver *self, PyObject *args) {
    Py_buffer data;
    PyObject *address;
    if (!PyArg_ParseTuple(args, "y*O", &data, &address)) return NULL;
    struct sockaddr_storage from;
    socklen_t from_len;
    if (parse_address(address, &from, &from_len) < 0 || data.len > MAX_DATAGRAM) {
        if (!PyErr_Occurred()) PyErr_SetString(PyExc_ValueError, "datagram too long");
        PyBuffer_Release(&data);
        return NULL;
    }
    /* A private copy: try_fast writes the encapsulation header into its buffer. */
    uint8_t *copy = malloc(data.len ? data.len : 1);
    memcpy(copy, data.buf, data.len);
    pthread_mutex_lock(&self->mutex);
    int taken = try_fast(self, copy, data.len, &from);
    if (!taken) queue_for_python(self, copy, data.len, &from, from_len);
    pthread_mutex_unlock(&self->mutex);
    free(copy);
    PyBuffer_Release(&data);
    return PyBool_FromLong(taken);
}

static PyObject *Receiver_notify_fd(Receiver *self, void *unused) {
    return PyLong_FromLong(self->notify_fd);
}

static PyMethodDef Receiver_methods[] = {
    {"start", (PyCFunction)Receiver_start, METH_NOARGS, "start the receive thread"},
    {"stop", (PyCFunction)Receiver_stop, METH_NOARGS, "stop and join the receive thread"},
    {"take", (PyCFunction)Receiver_take, METH_NOARGS, "[(datagram, address)] queued for Python"},
    {"finished", (PyCFunction)Receiver_finished, METH_O, "Python is done with N taken datagrams"},
    {"add_client", (PyCFunction)Receiver_add_client, METH_VARARGS, NULL},
    {"remove_client", (PyCFunction)Receiver_remove_client, METH_O, NULL},
    {"set_client_enabled", (PyCFunction)Receiver_set_client_enabled, METH_VARARGS, NULL},
    {"set_enabled", (PyCFunction)Receiver_set_enabled, METH_O, NULL},
    {"add_stream", (PyCFunction)Receiver_add_stream, METH_VARARGS, NULL},
    {"stream_accept", (PyCFunction)Receiver_stream_accept, METH_VARARGS, NULL},
    {"stream_seq", (PyCFunction)Receiver_stream_seq, METH_VARARGS, NULL},
    {"add_writer", (PyCFunction)Receiver_add_writer, METH_VARARGS, NULL},
    {"remove_writer", (PyCFunction)Receiver_remove_writer, METH_VARARGS, NULL},
    {"fold", (PyCFunction)Receiver_fold, METH_NOARGS, NULL},
    {"handle", (PyCFunction)Receiver_handle, METH_VARARGS, NULL},
    {NULL},
};

static PyGetSetDef Receiver_getset[] = {
    {"notify_fd", (getter)Receiver_notify_fd, NULL, "readable when take() has datagrams", NULL},
    {NULL},
};

static PyTypeObject ReceiverType = {
    PyVarObject_HEAD_INIT(NULL, 0)
    .tp_name = "xrce.agent._fastpath.Receiver",
    .tp_basicsize = sizeof(Receiver),
    .tp_flags = Py_TPFLAGS_DEFAULT,
    .tp_new = PyType_GenericNew,
    .tp_init = (initproc)Receiver_init,
    .tp_dealloc = (destructor)Receiver_dealloc,
    .tp_methods = Receiver_methods,
    .tp_getset = Receiver_getset,
};

/* resolve_rcl(): True once rcl_publish_serialized_message is found in an already loaded librcl. */
static PyObject *resolve_rcl(PyObject *module, PyObject *unused) {
    if (rcl_publish_serialized == NULL) {
        void *library = dlopen("librcl.so", RTLD_NOW | RTLD_NOLOAD);
        if (library != NULL) {
            rcl_publish_serialized = (publish_serialized_fn)dlsym(library,
                                                                  "rcl_publish_serialized_message");
            dlclose(library);  /* NOLOAD took a reference; rclpy holds its own */
        }
    }
    return PyBool_FromLong(rcl_publish_serialized != NULL);
}

static PyMethodDef module_methods[] = {
    {"resolve_rcl", resolve_rcl, METH_NOARGS, NULL},
    {NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "xrce.agent._fastpath", NULL, -1, module_methods,
};

PyMODINIT_FUNC PyInit__fastpath(void) {
    if (PyType_Ready(&ReceiverType) < 0) return NULL;
    PyObject *m = PyModule_Create(&module);
    if (m == NULL) return NULL;
    Py_INCREF(&ReceiverType);
    if (PyModule_AddObject(m, "Receiver", (PyObject *)&ReceiverType) < 0) {
        Py_DECREF(&ReceiverType);
        Py_DECREF(m);
        return NULL;
    }
    return m;
}
