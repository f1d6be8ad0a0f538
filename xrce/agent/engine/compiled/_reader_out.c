/* Samples from ROS to a board without the interpreter: a datareader's samples reach the receive
 * thread (_receive_thread.c), which sends them as DATA on the board's stream itself.
 *
 * Why: a board's reader (a TurtleBot3's cmd_vel, 30 a second) cost a wake-up of the rclpy
 * executor's thread per sample, with the GIL, and the engine's delivery in Python under its lock.
 *
 * How: the reader's rcl subscription is rclpy's, made by the middleware as before; once the
 * executor has taken it in, its on-new-message callback is pointed here instead (rclpy's events
 * executor sets that callback once, when it adds the subscription, and clears it when it removes
 * it). The callback, on Fast DDS's thread, only marks the reader and writes an eventfd: it takes
 * no lock, since Fast DDS calls it with its own held, from inside a publish of this very thread
 * too. The receive thread then takes each sample serialized (rcl_take_serialized_message) and,
 * under the Receiver's mutex:
 *   - sends it as the DATA Python's data_message would build (header, DATA submessage with the
 *     READ_DATA's request id and the reader's object id, the CDR body), on the stream the
 *     READ_DATA named: a reliable one's next sequence number (kept here for retransmission until
 *     acknowledged, _reliable_out.c) or a best-effort one's, when Python has set the reader direct
 *     (a READ_DATA without limits, nothing queued) and the client is enabled, the message fits
 *     the client's MTU and the window has room with nothing of Python's waiting for it;
 *   - else hands it to Python (the reader's ReaderHandoff, as the executor did), and stops
 *     sending the reader's samples itself until Python says so again, so samples keep their
 *     order: Python's queue drains first.
 * A reliable DATA sent here asks Python, once, for the HEARTBEAT round (heartbeat_due).
 *
 * rcl is not linked, as for publishing: the three functions are looked up in the rcl and rcutils
 * rclpy already loaded. */
#include "_fastpath.h"

#include <sys/eventfd.h>

#define RCL_RET_OK 0
#define DATA 0x09
#define DATA_FLAGS 0x01  /* little-endian, FORMAT_DATA */
#define ENCAPSULATION 4
#define MAX_TAKE_ROUND 64  /* samples of one reader per pass: the others get their turn */

typedef int (*take_serialized_fn)(const void *subscription, serialized_message_t *message,
                                  void *message_info, void *allocation);
typedef rcutils_allocator_t (*default_allocator_fn)(void);
typedef void *(*allocate_fn)(size_t size, void *state);
typedef void (*deallocate_fn)(void *pointer, void *state);

static set_event_callback_fn set_message_callback;
static take_serialized_fn take_serialized;
rcutils_allocator_t take_allocator;  /* rcutils' default: rmw may grow a buffer of it */

/* True once the functions are found in the rcl and rcutils already loaded. */
PyObject *resolve_rcl_readers(void) {
    if (take_serialized == NULL) {
        default_allocator_fn get_allocator =
            (default_allocator_fn)loaded_symbol("librcutils.so", "rcutils_get_default_allocator");
        set_event_callback_fn set_callback = (set_event_callback_fn)loaded_symbol(
            "librcl.so", "rcl_subscription_set_on_new_message_callback");
        take_serialized_fn take = (take_serialized_fn)loaded_symbol("librcl.so",
                                                                    "rcl_take_serialized_message");
        if (get_allocator && set_callback && take) {
            take_allocator = get_allocator();
            set_message_callback = set_callback;
            take_serialized = take;
        }
    }
    return PyBool_FromLong(take_serialized != NULL);
}

/* Fast DDS's thread, with its listener's lock held: no lock here, one write. A replier's
 * requests signal the same way (_replier_out.c). */
void on_new_message(const void *user_data, size_t count) {
    (void)count;
    Reader *r = (Reader *)user_data;
    __atomic_store_n(&r->signalled, 1, __ATOMIC_RELEASE);
    uint64_t one = 1;
    ssize_t written = write(r->receiver->samples_fd, &one, sizeof one);
    (void)written;  /* EAGAIN only when the counter is full: the thread is woken already */
}

static OutBestEffort *find_out_best_effort(Client *c, uint8_t stream_id) {
    for (OutBestEffort *b = c->out_best_effort; b; b = b->next)
        if (b->stream_id == stream_id) return b;
    return NULL;
}

/* Send ``lead`` (a replier's sample identity, else nothing) and ``length`` bytes of CDR
 * (encapsulation first) to the reader's client as one DATA; 0 when Python must have the sample.
 * Called locked. */
int send_direct(Receiver *self, Reader *r, const uint8_t *lead, size_t lead_length,
                const uint8_t *cdr, size_t length) {
    Client *c = r->client;
    if (c == NULL || r->request_id < 0 || !c->enabled || !self->enabled || length < ENCAPSULATION) return 0;
    size_t body = lead_length + length - ENCAPSULATION;
    size_t head = c->session_id < 0x80 ? 8 : 4;
    size_t total = head + 8 + body;
    if (total > c->mtu || body + 4 > 0xFFFF) return 0;  /* Python fragments or names it */
    OutStream *o = NULL;
    OutBestEffort *b = NULL;
    if (r->stream_id & 0x80) {
        o = find_out_stream(c, r->stream_id);
        if (o == NULL || o->held || (uint16_t)(o->last_sent - o->last_acknowledged) >= o->history)
            return 0;
    } else if ((b = find_out_best_effort(c, r->stream_id)) == NULL) {
        return 0;
    }
    uint8_t *message = malloc(total);
    if (message == NULL) return 0;
    uint16_t seq = (uint16_t)((o ? o->last_sent : b->last_sent) + 1);
    size_t n = 0;
    message[n++] = c->session_id;
    message[n++] = r->stream_id;
    message[n++] = seq & 0xFF, message[n++] = seq >> 8;
    if (head == 8) {
        memcpy(message + n, c->key, 4);
        n += 4;
    }
    uint16_t sub_length = (uint16_t)(4 + body);
    message[n++] = DATA, message[n++] = DATA_FLAGS;
    message[n++] = sub_length & 0xFF, message[n++] = sub_length >> 8;
    message[n++] = (uint8_t)(r->request_id >> 8), message[n++] = (uint8_t)r->request_id;
    message[n++] = r->object_id >> 8, message[n++] = r->object_id & 0xFF;
    if (lead_length) memcpy(message + n, lead, lead_length);
    memcpy(message + n + lead_length, cdr + ENCAPSULATION, length - ENCAPSULATION);
    /* A failed send is a datagram lost on the way, as Python's link counts it: a reliable
     * stream retransmits it when the board NACKs. */
    ssize_t sent = sendto(self->sock, message, total, MSG_DONTWAIT,
                          (const struct sockaddr *)&c->addr, c->addr_len);
    if (o) {
        unsigned slot = seq & (o->history - 1);
        free(o->slots[slot]);
        o->slots[slot] = message;
        o->lengths[slot] = (uint16_t)total;
        o->last_sent = seq;
        if (!self->heartbeat_due) {
            self->heartbeat_due = 1;
            wake_python(self);
        }
    } else {
        b->last_sent = seq;
        free(message);
    }
    if (sent == (ssize_t)total) {
        c->messages_out++;
        c->bytes_out += total;
        r->messages++;
        r->bytes += total;
    }
    r->samples++;
    r->sample_bytes += body;
    self->samples_out++;
    self->readers_counted = 1;
    return 1;
}

/* The receive thread's buffer for serialized samples, made on first use; 0 without memory. */
int ensure_take_buffer(Receiver *self) {
    if (self->take_buffer != NULL) return 1;
    self->take_buffer = ((allocate_fn)take_allocator.allocate)(1024, take_allocator.state);
    if (self->take_buffer == NULL) return 0;
    self->take_capacity = 1024;
    return 1;
}

void free_take_buffer(Receiver *self) {
    if (self->take_buffer != NULL)
        ((deallocate_fn)take_allocator.deallocate)(self->take_buffer, take_allocator.state);
    self->take_buffer = NULL;
    self->take_capacity = 0;
}

/* The receive thread, locked: every signalled reader's waiting samples. */
void deliver_samples(Receiver *self) {
    if (take_serialized == NULL || !ensure_take_buffer(self)) return;
    uint64_t info[32];  /* rmw_message_info_t, written by rmw and not read here */
    for (Reader *r = self->readers; r; r = r->next) {
        if (!__atomic_exchange_n(&r->signalled, 0, __ATOMIC_ACQ_REL)) continue;
        if (r->service) {  /* a replier's requests */
            deliver_requests(self, r);
            continue;
        }
        int taken;
        for (taken = 0; taken < MAX_TAKE_ROUND; taken++) {
            serialized_message_t message = {self->take_buffer, 0, self->take_capacity, take_allocator};
            int ret = take_serialized(r->subscription, &message, info, NULL);
            /* rmw grows the buffer with the allocator when a sample needs more */
            self->take_buffer = message.buffer;
            self->take_capacity = message.buffer_capacity;
            if (ret != RCL_RET_OK) break;  /* nothing left (or the subscription failed) */
            if (send_direct(self, r, NULL, 0, message.buffer, message.buffer_length)) continue;
            r->request_id = -1;  /* Python's until it has delivered what it holds */
            if (!handoff_append(self, r->token, message.buffer, message.buffer_length, NULL, 0))
                self->handoff_dropped++;  /* counted, as ReaderHandoff drops beyond its depth */
            wake_python(self);
        }
        if (taken == MAX_TAKE_ROUND) {  /* more may wait: the next pass takes them */
            __atomic_store_n(&r->signalled, 1, __ATOMIC_RELEASE);
            uint64_t one = 1;
            ssize_t written = write(self->samples_fd, &one, sizeof one);
            (void)written;
        }
    }
}

/* The client goes from the tables (Python dropped it): its readers stay, every sample Python's,
 * until Python registers the client again (set_reader_client) or removes them; rclpy's executor
 * would not take the subscriptions back (it sets their callback only when it adds them). Called
 * locked. */
void detach_readers(Receiver *self, Client *c) {
    for (Reader *r = self->readers; r; r = r->next) {
        if (r->client != c) continue;
        r->client = NULL;
        r->request_id = -1;
    }
}

/* Unset every reader's callback (rmw calls it no more once that returns) and free them. */
void free_readers(Receiver *self) {
    for (Reader *r = self->readers, *n; r; r = n) {
        n = r->next;
        if (r->set_callback) r->set_callback(r->subscription, NULL, NULL);
        free_service_part(r);
        free(r);
    }
    self->readers = NULL;
}

/* ----------------------------------------------------------------------------- Python side */

/* Put ``r`` in the readers of client ``handle`` for the rcl entity at ``address`` and point the
 * entity's callback here (rmw calls it at once for what already waits): its token; 0 when the
 * client is not registered, -1 when rcl refused the callback (``r`` is the caller's to free). */
long link_reader(Receiver *self, Reader *r, long handle, int object_id,
                 unsigned long long address, set_event_callback_fn set_callback) {
    long token = 0;
    pthread_mutex_lock(&self->mutex);
    Client *c = client_by_handle(self, handle);
    if (c != NULL) {
        r->client = c;
        r->receiver = self;
        r->object_id = (uint16_t)object_id;
        r->subscription = (const void *)(uintptr_t)address;
        r->request_id = -1;
        r->set_callback = set_callback;
        r->token = token = ++self->next_reader_token;
        r->next = self->readers;
        self->readers = r;
        if (set_callback(r->subscription, on_new_message, r) != RCL_RET_OK) {
            self->readers = r->next;
            token = -1;
        }
    }
    pthread_mutex_unlock(&self->mutex);
    return token;
}

/* add_reader(handle, object_id, subscription address) -> token (> 0), or 0 when the client is
 * not registered: from now on the reader's samples reach the receive thread first. Call it once
 * rclpy's executor has taken the subscription in (it sets the callback when it does). */
PyObject *Receiver_add_reader(Receiver *self, PyObject *args) {
    long handle;
    int object_id;
    unsigned long long address;
    if (!PyArg_ParseTuple(args, "liK", &handle, &object_id, &address)) return NULL;
    if (take_serialized == NULL || !self->running) {
        PyErr_SetString(PyExc_RuntimeError, "rcl's take not resolved, or no receive thread");
        return NULL;
    }
    Reader *r = calloc(1, sizeof *r);
    if (r == NULL) return PyErr_NoMemory();
    long token = link_reader(self, r, handle, object_id, address, set_message_callback);
    if (token <= 0) free(r);
    if (token < 0) {
        PyErr_SetString(PyExc_RuntimeError, "rcl refused the subscription's callback");
        return NULL;
    }
    return PyLong_FromLong(token);
}

/* remove_reader(token) -> (samples, sample bytes, messages, bytes) it sent since the last fold,
 * or None: before the subscription is destroyed (rmw calls the callback no more afterwards). */
PyObject *Receiver_remove_reader(Receiver *self, PyObject *arg) {
    long token = PyLong_AsLong(arg);
    if (token == -1 && PyErr_Occurred()) return NULL;
    PyObject *counts = NULL;
    pthread_mutex_lock(&self->mutex);
    for (Reader **link = &self->readers; *link; link = &(*link)->next) {
        Reader *r = *link;
        if (r->token != token) continue;
        r->set_callback(r->subscription, NULL, NULL);
        *link = r->next;
        counts = Py_BuildValue("(KKKK)", (unsigned long long)r->samples,
                               (unsigned long long)r->sample_bytes,
                               (unsigned long long)r->messages, (unsigned long long)r->bytes);
        free_service_part(r);
        free(r);
        break;
    }
    pthread_mutex_unlock(&self->mutex);
    if (counts == NULL && PyErr_Occurred()) return NULL;
    if (counts == NULL) Py_RETURN_NONE;
    return counts;
}

/* reclaim_reader(token): the subscription's callback is C's again. rclpy's events executor sets
 * its own when it adds a subscription, which can be after C took it (a domain joined with the
 * client's first CREATEs adds its entities to the executor once that burst is over): Python calls
 * this when the executor delivers a sample of a reader C holds. */
PyObject *Receiver_reclaim_reader(Receiver *self, PyObject *arg) {
    long token = PyLong_AsLong(arg);
    if (token == -1 && PyErr_Occurred()) return NULL;
    int found = 0;
    pthread_mutex_lock(&self->mutex);
    for (Reader *r = self->readers; r; r = r->next) {
        if (r->token != token) continue;
        found = r->set_callback(r->subscription, on_new_message, r) == RCL_RET_OK;
        break;
    }
    pthread_mutex_unlock(&self->mutex);
    return PyBool_FromLong(found);
}

/* set_reader_client(token, handle) -> True if both are registered: the reader's samples may be
 * sent to that client (again) once Python sets it direct. */
PyObject *Receiver_set_reader_client(Receiver *self, PyObject *args) {
    long token, handle;
    if (!PyArg_ParseTuple(args, "ll", &token, &handle)) return NULL;
    int found = 0;
    pthread_mutex_lock(&self->mutex);
    Client *c = client_by_handle(self, handle);
    for (Reader *r = self->readers; r && c; r = r->next) {
        if (r->token != token) continue;
        r->client = c;
        r->request_id = -1;
        found = 1;
        break;
    }
    pthread_mutex_unlock(&self->mutex);
    return PyBool_FromLong(found);
}

/* set_reader_direct(token, request_id, stream_id, mtu): send the reader's samples here as DATA
 * for that READ_DATA (request_id -1: hand every sample to Python). */
PyObject *Receiver_set_reader_direct(Receiver *self, PyObject *args) {
    long token;
    int request_id, stream_id, mtu;
    if (!PyArg_ParseTuple(args, "liii", &token, &request_id, &stream_id, &mtu)) return NULL;
    int found = 0;
    pthread_mutex_lock(&self->mutex);
    for (Reader *r = self->readers; r; r = r->next) {
        if (r->token != token || r->client == NULL) continue;
        r->request_id = request_id < 0 ? -1 : (request_id & 0xFFFF);
        r->stream_id = (uint8_t)stream_id;
        r->client->mtu = (uint16_t)(mtu > 0xFFFF ? 0xFFFF : mtu);
        found = 1;
        break;
    }
    pthread_mutex_unlock(&self->mutex);
    return PyBool_FromLong(found);
}

/* heartbeat_due(clear) -> whether DATA went out here on a reliable stream since Python last
 * cleared it (its HEARTBEAT round then covers those messages). */
PyObject *Receiver_heartbeat_due(Receiver *self, PyObject *arg) {
    int clear = PyObject_IsTrue(arg);
    if (clear < 0) return NULL;
    pthread_mutex_lock(&self->mutex);
    int due = self->heartbeat_due;
    if (clear) self->heartbeat_due = 0;
    pthread_mutex_unlock(&self->mutex);
    return PyBool_FromLong(due);
}

/* fold_readers() -> None, or ((samples, messages, bytes), [(token, object_id, samples,
 * sample bytes, messages, bytes)]) sent here since the last call, reset here (a row names its
 * reader by token). */
PyObject *Receiver_fold_readers(Receiver *self, PyObject *unused) {
    pthread_mutex_lock(&self->mutex);
    if (self->samples_out == 0 && !self->readers_counted) {
        pthread_mutex_unlock(&self->mutex);
        Py_RETURN_NONE;
    }
    self->readers_counted = 0;
    PyObject *rows = PyList_New(0);
    uint64_t messages = 0, bytes = 0;
    for (Reader *r = self->readers; r && rows; r = r->next) {
        if (!r->samples) continue;
        PyObject *row = Py_BuildValue("(liKKKK)", r->token, (int)r->object_id,
                                      (unsigned long long)r->samples,
                                      (unsigned long long)r->sample_bytes,
                                      (unsigned long long)r->messages,
                                      (unsigned long long)r->bytes);
        if (row == NULL || PyList_Append(rows, row) < 0) Py_CLEAR(rows);
        Py_XDECREF(row);
        messages += r->messages;
        bytes += r->bytes;
        r->samples = r->sample_bytes = r->messages = r->bytes = 0;
    }
    PyObject *result = rows ? Py_BuildValue("((KKK)N)", (unsigned long long)self->samples_out,
                                            (unsigned long long)messages,
                                            (unsigned long long)bytes, rows) : NULL;
    self->samples_out = 0;
    pthread_mutex_unlock(&self->mutex);
    return result;
}

/* add_out_best_effort(handle, stream_id, last_sent) -> True if the client is registered: the
 * stream's sequence numbers live here from now on. */
PyObject *Receiver_add_out_best_effort(Receiver *self, PyObject *args) {
    long handle;
    int stream_id, last_sent;
    if (!PyArg_ParseTuple(args, "lii", &handle, &stream_id, &last_sent)) return NULL;
    pthread_mutex_lock(&self->mutex);
    Client *c = client_by_handle(self, handle);
    OutBestEffort *b = c ? find_out_best_effort(c, (uint8_t)stream_id) : NULL;
    if (c && b == NULL && (b = calloc(1, sizeof *b)) != NULL) {
        b->stream_id = (uint8_t)stream_id;
        b->next = c->out_best_effort;
        c->out_best_effort = b;
    }
    if (b) b->last_sent = (uint16_t)last_sent;
    pthread_mutex_unlock(&self->mutex);
    if (c && b == NULL) return PyErr_NoMemory();
    return PyBool_FromLong(b != NULL);
}

/* out_best_effort_next(handle, stream_id) -> the next sequence number of the stream, taken now
 * (-1 for the last one sent, without taking one), or None if it is not registered. */
PyObject *Receiver_out_best_effort_next(Receiver *self, PyObject *args) {
    long handle;
    int stream_id, take = 1;
    if (!PyArg_ParseTuple(args, "li|p", &handle, &stream_id, &take)) return NULL;
    long seq = -1;
    pthread_mutex_lock(&self->mutex);
    Client *c = client_by_handle(self, handle);
    OutBestEffort *b = c ? find_out_best_effort(c, (uint8_t)stream_id) : NULL;
    if (b) {
        if (take) b->last_sent++;
        seq = b->last_sent;
    }
    pthread_mutex_unlock(&self->mutex);
    if (seq < 0) Py_RETURN_NONE;
    return PyLong_FromLong(seq);
}
