/* The compiled receive path's tables, as Python fills them (xrce.agent.engine.compiled.fastpath): the
 * clients it may serve and their addresses, their streams and each stream's state, the writers it
 * may publish for. Registration runs on the loop's thread; the mutex keeps the receive thread
 * from seeing a table half changed. */
#include "_fastpath.h"

int parse_address(PyObject *tuple, struct sockaddr_storage *out, socklen_t *len) {
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

void free_client(Client *c) {
    for (Writer *w = c->writers, *n; w; w = n) { n = w->next; free(w); }
    for (Stream *s = c->streams, *n; s; s = n) { n = s->next; free_reassembly(s); free(s); }
    free_out_streams(c);
    free(c);
}

PyObject *Receiver_add_client(Receiver *self, PyObject *args) {
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
    if (parse_address(address, &c->addr, &c->addr_len) < 0) {
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

PyObject *Receiver_remove_client(Receiver *self, PyObject *arg) {
    long handle = PyLong_AsLong(arg);
    if (handle == -1 && PyErr_Occurred()) return NULL;
    pthread_mutex_lock(&self->mutex);
    for (Client **link = &self->clients; *link; link = &(*link)->next) {
        if ((*link)->handle == handle) {
            Client *c = *link;
            *link = c->next;
            int kept = 0;
            for (int i = 0; i < self->pending_count; i++)
                if (self->pending[i].client != c) self->pending[kept++] = self->pending[i];
            self->pending_count = kept;
            detach_readers(self, c);
            free_client(c);
            break;
        }
    }
    pthread_mutex_unlock(&self->mutex);
    Py_RETURN_NONE;
}

PyObject *Receiver_set_client_enabled(Receiver *self, PyObject *args) {
    long handle;
    int enabled;
    if (!PyArg_ParseTuple(args, "lp", &handle, &enabled)) return NULL;
    pthread_mutex_lock(&self->mutex);
    Client *c = client_by_handle(self, handle);
    if (c) c->enabled = enabled;
    pthread_mutex_unlock(&self->mutex);
    Py_RETURN_NONE;
}

PyObject *Receiver_set_enabled(Receiver *self, PyObject *arg) {
    int enabled = PyObject_IsTrue(arg);
    if (enabled < 0) return NULL;
    pthread_mutex_lock(&self->mutex);
    self->enabled = enabled;
    pthread_mutex_unlock(&self->mutex);
    Py_RETURN_NONE;
}

/* add_stream(handle, stream_id, last_seq[, last_announced]): from now on the sequence number
 * lives here; with last_announced, a reliable stream's (InputReliableStream's two numbers). */
PyObject *Receiver_add_stream(Receiver *self, PyObject *args) {
    long handle;
    int stream_id, last_seq, last_announced = -1;
    if (!PyArg_ParseTuple(args, "lii|i", &handle, &stream_id, &last_seq, &last_announced))
        return NULL;
    pthread_mutex_lock(&self->mutex);
    Client *c = client_by_handle(self, handle);
    Stream *s = c ? find_stream(c, (uint8_t)stream_id) : NULL;
    if (c && s == NULL && (s = calloc(1, sizeof *s)) != NULL) {
        s->stream_id = (uint8_t)stream_id;
        s->next = c->streams;
        c->streams = s;
    }
    if (s) {
        s->last_seq = (uint16_t)last_seq;
        s->reliable = last_announced >= 0;
        s->last_announced = s->reliable ? (uint16_t)last_announced : 0;
        s->ack_due = 0;
    }
    pthread_mutex_unlock(&self->mutex);
    if (c && s == NULL) return PyErr_NoMemory();
    return PyBool_FromLong(s != NULL);
}

/* reliable_state(handle, stream_id) -> (last_handled, last_announced) or None. */
PyObject *Receiver_reliable_state(Receiver *self, PyObject *args) {
    long handle;
    int stream_id;
    if (!PyArg_ParseTuple(args, "li", &handle, &stream_id)) return NULL;
    long last = -1, announced = 0;
    pthread_mutex_lock(&self->mutex);
    Client *c = client_by_handle(self, handle);
    Stream *s = c ? find_stream(c, (uint8_t)stream_id) : NULL;
    if (s && s->reliable) last = s->last_seq, announced = s->last_announced;
    pthread_mutex_unlock(&self->mutex);
    if (last < 0) Py_RETURN_NONE;
    return Py_BuildValue("(ll)", last, announced);
}

/* set_reliable_state(handle, stream_id, last_handled, last_announced): Python's stream moved. */
PyObject *Receiver_set_reliable_state(Receiver *self, PyObject *args) {
    long handle;
    int stream_id, last, announced;
    if (!PyArg_ParseTuple(args, "liii", &handle, &stream_id, &last, &announced)) return NULL;
    int found = 0;
    pthread_mutex_lock(&self->mutex);
    Client *c = client_by_handle(self, handle);
    Stream *s = c ? find_stream(c, (uint8_t)stream_id) : NULL;
    if (s && s->reliable) {
        s->last_seq = (uint16_t)last, s->last_announced = (uint16_t)announced;
        found = 1;
    }
    pthread_mutex_unlock(&self->mutex);
    return PyBool_FromLong(found);
}

/* stream_accept(handle, stream_id, seq): the best-effort check for a datagram Python handles. */
PyObject *Receiver_stream_accept(Receiver *self, PyObject *args) {
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

PyObject *Receiver_stream_seq(Receiver *self, PyObject *args) {
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
PyObject *Receiver_add_writer(Receiver *self, PyObject *args) {
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

/* remove_writer(handle, object_id): returns (samples, bytes) not folded yet. Once it returns,
 * nothing here refers to the publisher any more (the mutex covers every publish). */
PyObject *Receiver_remove_writer(Receiver *self, PyObject *args) {
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
