/* Optional compiled receive path of the UDP link: WRITE_DATA straight into rcl.
 *
 * Why it exists: per datagram, the Python data path had reached its floor (bench/agent/cost.py);
 * what is left of the cost is Python work, not the kernel. Here the UDP link's socket is read on
 * a thread of the module's own (_receive_thread.c), in recvmmsg batches, without the GIL. A
 * datagram whose every submessage is a WRITE_DATA (FORMAT_DATA) to a datawriter Python registered,
 * on a best-effort stream Python registered, is published with rcl_publish_serialized_message
 * right here (try_fast). So is, on a reliable stream Python registered, a datagram holding one
 * such WRITE_DATA that is the next message in order (try_fast_reliable), and the ACKNACK it owes
 * is sent here at the end of the batch, or by Python (send_due_acknacks says when). FRAGMENTs of
 * such a stream and the client's HEARTBEATs for it are _reliable_in.c's (try_fast_fragment,
 * try_fast_heartbeat), a client's TIMESTAMPs are answered here (try_fast_timestamp), the client's
 * plain ACKNACKs for the agent's reliable output streams are _reliable_out.c's. The tables Python
 * fills (clients, streams, writers) are _receiver_tables.c's. The ROS type supports and conversions
 * the middleware uses are another extension's (xrce/agent/middleware/ros/_rostypes.c).
 * A datagram that is none of these (other reliable messages, control, unknown clients, anything
 * malformed, a failed reliable publish) is handed to Python unchanged, and so is every datagram
 * behind it until Python has handled them, so every decision Python makes it still makes in
 * arrival order. xrce/agent/engine/compiled/fastpath.py is the Python side.
 *
 * History: this path first read on the asyncio loop's thread, and a thread of its own was measured
 * and dropped then: with only best-effort samples taken here, every other datagram cost two
 * wake-ups. Once reliable samples, fragments, HEARTBEATs, ACKNACKs and TIMESTAMPs were taken here
 * too, the loop's wake-ups were the larger cost (the TurtleBot3 load: ~120 a second for datagrams
 * C took whole), and the thread came back.
 *
 * Ownership: Python decides what is fast (clients, streams, writers and their rcl publishers) and
 * removes a writer before it destroys the publisher. This module owns the input sequence number of
 * every registered stream: Python asks it (stream_accept) for the datagrams it handles itself, and
 * a registered reliable stream's two numbers (reliable_state, set_reliable_state) whenever its
 * InputReliableStream reads or moves them (xrce.agent.engine.compiled.streams.CompiledReliableStream).
 * Counters accumulate here and Python folds them into its own (fold) whenever it runs for the link.
 *
 * rcl is not linked: the function is looked up in the librcl rclpy already loaded, so the module
 * builds with no ROS headers, and without rclpy loaded the Python path simply stays in charge.
 */
#include "_fastpath.h"

publish_serialized_fn rcl_publish_serialized;

/* ``symbol`` of a library rclpy already loaded (librcl.so, librcutils.so), NULL without one. A
 * handle's lookup covers the libraries it depends on: through librcl this finds rmw's functions
 * in whichever rmw library rcl is linked to, and rcutils'. The ROS extension has its own
 * (xrce_rcl_symbol): two extensions do not link each other's functions. */
void *loaded_symbol(const char *library_name, const char *symbol) {
    void *library = dlopen(library_name, RTLD_NOW | RTLD_NOLOAD);
    if (library == NULL) return NULL;
    void *found = dlsym(library, symbol);
    dlclose(library);  /* NOLOAD took a reference; rclpy holds its own */
    return found;
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
        if (c->session_id != data[0] || !same_address(&c->addr, from)) continue;
        if (data[0] >= 0x80 || memcmp(c->key, data + 4, 4) == 0) return c;
    }
    return NULL;
}

/* The reliable stream handled message ``seq`` (``length`` bytes) here: it moves, owes an ACKNACK
 * (sent at the end of the batch) and counts the message as Python would. Called locked. */
void stream_delivered(Receiver *self, Client *client, Stream *stream, uint16_t seq, size_t length) {
    stream->last_seq = seq;
    if (seq_less(stream->last_announced, seq)) stream->last_announced = seq;
    if (!stream->ack_due) {
        if (self->pending_count < PENDING_ACKS) {
            self->pending[self->pending_count].client = client;
            self->pending[self->pending_count++].stream = stream;
        } else {
            self->pending_overflow = 1;  /* fold's walk finds it: Python acknowledges it */
        }
    }
    stream->ack_due = 1;
    count_message(self, client, length);
}

/* A reliable stream's datagram: taken here only if it is the next message in order, with nothing
 * held for the stream in Python, and its one submessage a WRITE_DATA to a registered writer that
 * publishes. Everything else (a duplicate, a gap, a retransmission filling one, several
 * submessages, a failed publish) goes to Python unchanged, which decides and acknowledges as it
 * does for any reliable message; this path changes the stream only for a sample it delivered.
 * Python keeps out-of-order messages with sequence numbers up to last_announced (its
 * InputReliableStream invariant), so one not after seq means Python holds nothing to pop behind
 * it. Called locked. */
static int try_fast_reliable(Receiver *self, Client *client, Stream *stream, uint8_t *data,
                             size_t length) {
    uint16_t seq = data[2] | (data[3] << 8);
    if (seq != (uint16_t)(stream->last_seq + 1) || seq_less(seq, stream->last_announced)) return 0;
    size_t pos = data[0] < 0x80 ? 8 : 4;
    size_t sub_length = data[pos + 2] | (data[pos + 3] << 8);  /* try_fast: length >= 12 */
    if (data[pos] == FRAGMENT && pos + 4 + sub_length == length)  /* _reliable_in.c */
        return try_fast_fragment(self, client, stream, data, length, pos, sub_length);
    if (pos + 8 > length) return 0;
    /* up to 3 bytes of alignment padding may follow (PX4's client pads every datagram) */
    size_t end = pos + 4 + sub_length;
    if (data[pos] != WRITE_DATA || (data[pos + 1] & FORMAT_MASK) != FORMAT_DATA ||
        sub_length < 4 || end > length || length > ((end + 3) & ~(size_t)3))
        return 0;
    uint16_t object_id = (uint16_t)(data[pos + 6] << 8 | data[pos + 7]);
    Writer *writer = find_writer(client, object_id);
    if (writer == NULL) {  /* a reply to a request the receive thread sent (_replier_out.c) */
        Reader *replier = find_replier(self, client, object_id);
        if (replier == NULL || replier_reply(self, replier, data + pos + 8, sub_length - 4, 0) != 1)
            return 0;
        stream_delivered(self, client, stream, seq, length);
        self->samples++;
        replier->samples++;
        replier->sample_bytes += sub_length - 4;
        self->readers_counted = 1;
        return 1;
    }
    uint8_t *body = data + pos + 4, ids[4];
    memcpy(ids, body, 4);
    body[0] = 0x00, body[1] = 0x01, body[2] = 0x00, body[3] = 0x00;
    serialized_message_t message = {body, sub_length, sub_length, {0}};
    if (rcl_publish_serialized(writer->publisher, &message, NULL) != 0) {
        memcpy(body, ids, 4);  /* Python gets the datagram as it came */
        return 0;
    }
    stream_delivered(self, client, stream, seq, length);
    self->samples++;
    writer->samples++;
    writer->sample_bytes += sub_length - 4;
    return 1;
}

static void put_time(uint8_t *out, int64_t ns) {
    int64_t sec = ns / 1000000000, nsec = ns % 1000000000;
    if (nsec < 0) sec -= 1, nsec += 1000000000;  /* as Python's floor division encodes it */
    uint32_t s = (uint32_t)(int32_t)sec, n = (uint32_t)nsec;
    for (int i = 0; i < 4; i++) out[i] = (uint8_t)(s >> (8 * i)), out[4 + i] = (uint8_t)(n >> (8 * i));
}

static int64_t time_of_day_ns(void) {
    struct timespec ts;
    clock_gettime(CLOCK_REALTIME, &ts);
    return (int64_t)ts.tv_sec * 1000000000 + ts.tv_nsec;
}

/* A datagram that is one little-endian TIMESTAMP: answered here with the bytes the Python path
 * sends (xrce.agent.engine.inbound, a test holds them equal): TIMESTAMP_REPLY on stream none,
 * the time of day at transmit and at receive, the client's time echoed. PX4 counts only round
 * trips under 10 ms towards its time sync and sends one in its loop among its samples: answered
 * here, it waits for nothing in Python, nor does the rest of the batch behind it. 1 if sent. */
static int try_fast_timestamp(Receiver *self, Client *c, const uint8_t *data, size_t length) {
    size_t pos = data[0] < 0x80 ? 8 : 4;
    if (length != pos + 12 || data[pos] != TIMESTAMP || !(data[pos + 1] & 0x01) ||
        (data[pos + 2] | data[pos + 3] << 8) != 8)
        return 0;
    int64_t received = time_of_day_ns();
    const uint8_t *t = data + pos + 4;
    int32_t sec = (int32_t)((uint32_t)t[0] | (uint32_t)t[1] << 8 | (uint32_t)t[2] << 16 |
                            (uint32_t)t[3] << 24);
    uint32_t nsec = (uint32_t)t[4] | (uint32_t)t[5] << 8 | (uint32_t)t[6] << 16 |
                    (uint32_t)t[7] << 24;
    if (nsec >= 1000000000u) return 0;  /* Python normalizes such a time in its echo */
    uint8_t reply[8 + 4 + 24];
    size_t n = 0;
    reply[n++] = c->session_id;
    reply[n++] = 0, reply[n++] = 0, reply[n++] = 0;  /* stream none, sequence 0 */
    if (c->session_id < 0x80) {
        memcpy(reply + n, c->key, 4);
        n += 4;
    }
    reply[n++] = TIMESTAMP_REPLY, reply[n++] = 0x01, reply[n++] = 24, reply[n++] = 0;
    put_time(reply + n + 8, received);
    memcpy(reply + n + 16, t, 8);
    put_time(reply + n, time_of_day_ns());
    n += 24;
    if (sendto(self->sock, reply, n, MSG_DONTWAIT, (const struct sockaddr *)&c->addr,
               c->addr_len) != (ssize_t)n)
        return 0;
    count_message(self, c, length);
    c->messages_out++;
    c->bytes_out += n;
    c->timestamp_skew_ns = received - ((int64_t)sec * 1000000000 + nsec);
    c->has_skew = 1;
    self->timestamp_replies++;
    self->timestamp_reply_bytes += n;
    return 1;
}

/* Publish the datagram here if all of it is fast; 0 when Python must have it. Called locked. */
int try_fast(Receiver *self, uint8_t *data, size_t length, const struct sockaddr_storage *from) {
    if (!self->enabled || rcl_publish_serialized == NULL || length < 12) return 0;
    uint8_t session_id = data[0];
    if ((session_id & 0x7F) == 0) return 0;
    Client *client = find_client(self, data, from);
    if (client == NULL || !client->enabled) return 0;
    if (data[1] == 0)  /* _reliable_in.c, _reliable_out.c */
        return try_fast_heartbeat(self, client, data, length) ||
               try_fast_acknack(self, client, data, length) ||
               try_fast_timestamp(self, client, data, length);
    Stream *stream = find_stream(client, data[1]);
    if (stream == NULL) return 0;
    if (stream->reliable) return try_fast_reliable(self, client, stream, data, length);
    /* Every submessage must be a WRITE_DATA to a registered writer, or Python takes it all:
     * the same walk as xrce/wire/message.py iter_submessages, every length checked. */
    size_t pos = session_id < 0x80 ? 8 : 4, count = 0;
    while (pos + 4 <= length) {
        size_t sub_length = data[pos + 2] | (data[pos + 3] << 8);
        size_t end = pos + 4 + sub_length;
        if (data[pos] != WRITE_DATA || (data[pos + 1] & FORMAT_MASK) != FORMAT_DATA ||
            sub_length < 4 || end > length ||
            find_writer(client, (uint16_t)(data[pos + 6] << 8 | data[pos + 7])) == NULL)
            return 0;
        count++;
        pos = (end + 3) & ~(size_t)3;
    }
    if (count == 0) return 0;
    uint16_t seq = data[2] | (data[3] << 8);
    count_message(self, client, length);
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

/* The ACKNACK xrce.agent.engine.liveliness._send_acknack sends (the same bytes: a test holds them
 * equal). 1 if sent. */
int send_stream_acknack(Receiver *self, Client *c, Stream *s, uint16_t bitmap) {
    uint8_t message[17];
    size_t n = 0;
    uint16_t first = (uint16_t)(s->last_seq + 1);
    message[n++] = c->session_id;
    message[n++] = 0, message[n++] = 0, message[n++] = 0;  /* stream none, sequence 0 */
    if (c->session_id < 0x80) {
        memcpy(message + n, c->key, 4);
        n += 4;
    }
    message[n++] = ACKNACK, message[n++] = 0x01, message[n++] = 5, message[n++] = 0;
    message[n++] = first & 0xFF, message[n++] = first >> 8;
    /* the bitmap as the encoder writes it: its first byte the higher sequence numbers */
    message[n++] = bitmap >> 8, message[n++] = bitmap & 0xFF;
    message[n++] = s->stream_id;
    if (sendto(self->sock, message, n, MSG_DONTWAIT, (const struct sockaddr *)&c->addr,
               c->addr_len) != (ssize_t)n)
        return 0;
    c->messages_out++;
    c->bytes_out += n;
    self->acknacks++;
    self->acknack_bytes += n;
    return 1;
}

/* The ACKNACK each pending stream owes, sent here as xrce.agent.engine.liveliness._send_acknack
 * would (the same bytes: a test holds them equal), when Python holds nothing out of order for it
 * (last_announced is last_seq: the NACK bitmap is empty). A stream that does not qualify, or whose
 * send fails, keeps ack_due: fold hands it to Python. Called locked, after a batch handled whole,
 * so a stream gets one ACKNACK per batch, as on the Python path. Returns how many streams still
 * owe one (Python's to send: the thread wakes Python for them). */
int send_due_acknacks(Receiver *self) {
    int owing = self->pending_overflow;
    self->pending_overflow = 0;
    for (int i = 0; i < self->pending_count; i++) {
        Client *c = self->pending[i].client;
        Stream *s = self->pending[i].stream;
        if (!s->ack_due) continue;
        if (c->enabled && s->last_announced == s->last_seq && send_stream_acknack(self, c, s, 0))
            s->ack_due = 0;  /* 0: nothing missing */
        else
            owing++;
    }
    self->pending_count = 0;
    return owing;
}

/* ----------------------------------------------------------------------------- Python side */

PyObject *address_tuple(const struct sockaddr_storage *addr) {
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

static int Receiver_init(Receiver *self, PyObject *args, PyObject *kwargs) {
    static char *names[] = {"sock", NULL};
    if (!PyArg_ParseTupleAndKeywords(args, kwargs, "i", names, &self->sock)) return -1;
    pthread_mutex_init(&self->mutex, NULL);
    self->control_fd = self->notify_fd = self->samples_fd = -1;
    self->enabled = 1;
    self->next_handle = 1;
    return 0;
}

static void Receiver_dealloc(Receiver *self) {
    stop_receive_thread(self);  /* before the tables it reads go */
    free_readers(self);         /* rmw calls back no more */
    if (self->samples_fd >= 0) close(self->samples_fd);
    free_take_buffer(self);
    for (Client *c = self->clients, *n; c; c = n) { n = c->next; free_client(c); }
    if (self->buffers) munmap(self->buffers, (size_t)BATCH * MAX_DATAGRAM);
    pthread_mutex_destroy(&self->mutex);
    Py_TYPE(self)->tp_free((PyObject *)self);
}

/* The batch's buffers, BATCH * 64 KB mapped once: only the pages datagrams touch become
 * resident. -1 (errno set) if the mapping failed. */
int map_buffers(Receiver *self) {
    if (self->buffers != NULL) return 0;
    void *map = mmap(NULL, (size_t)BATCH * MAX_DATAGRAM, PROT_READ | PROT_WRITE,
                     MAP_PRIVATE | MAP_ANONYMOUS, -1, 0);
    if (map == MAP_FAILED) return -1;
    self->buffers = map;
    for (int i = 0; i < BATCH; i++) {
        self->vectors[i].iov_base = self->buffers[i];
        self->vectors[i].iov_len = MAX_DATAGRAM;
        self->messages_hdr[i].msg_hdr.msg_iov = &self->vectors[i];
        self->messages_hdr[i].msg_hdr.msg_iovlen = 1;
        self->messages_hdr[i].msg_hdr.msg_name = &self->sources[i];
        self->messages_hdr[i].msg_hdr.msg_namelen = sizeof self->sources[i];
    }
    return 0;
}

/* fold(): the counters since the previous fold, reset here:
 * ((messages, bytes, samples, stale, publish_errors, acknacks sent, their bytes,
 *   TIMESTAMP_REPLYs sent, their bytes),
 *  [(handle, messages, bytes, last_seen_ns, messages_out, bytes_out, timestamp skew ns or None)],
 *  [(handle, object_id, samples, bytes)],
 *  [(handle, stream_id)] of the reliable streams that handled a message: each owes an ACKNACK) */
static PyObject *Receiver_fold(Receiver *self, PyObject *unused) {
    PyObject *clients = PyList_New(0), *writers = PyList_New(0), *acks = PyList_New(0);
    PyObject *result = NULL;
    if (clients == NULL || writers == NULL || acks == NULL) goto done;
    pthread_mutex_lock(&self->mutex);
    int failed = 0;
    for (Client *c = self->clients; c && !failed; c = c->next) {
        if (c->messages || c->messages_out) {
            PyObject *skew = c->has_skew ? PyLong_FromLongLong(c->timestamp_skew_ns)
                                         : Py_NewRef(Py_None);
            PyObject *row = skew ? Py_BuildValue("(lKKLKKN)", c->handle,
                                                 (unsigned long long)c->messages,
                                                 (unsigned long long)c->bytes,
                                                 (long long)c->last_seen_ns,
                                                 (unsigned long long)c->messages_out,
                                                 (unsigned long long)c->bytes_out, skew) : NULL;
            failed = row == NULL || PyList_Append(clients, row) < 0;
            Py_XDECREF(row);
            c->messages = c->bytes = c->messages_out = c->bytes_out = 0;
            c->has_skew = 0;
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
        for (Stream *s = c->streams; s && !failed; s = s->next) {
            if (!s->ack_due) continue;
            PyObject *row = Py_BuildValue("(li)", c->handle, (int)s->stream_id);
            failed = row == NULL || PyList_Append(acks, row) < 0;
            Py_XDECREF(row);
            s->ack_due = 0;
        }
    }
    PyObject *totals = Py_BuildValue("(KKKKKKKKK)", (unsigned long long)self->messages,
                                     (unsigned long long)self->bytes,
                                     (unsigned long long)self->samples,
                                     (unsigned long long)self->stale,
                                     (unsigned long long)self->publish_errors,
                                     (unsigned long long)self->acknacks,
                                     (unsigned long long)self->acknack_bytes,
                                     (unsigned long long)self->timestamp_replies,
                                     (unsigned long long)self->timestamp_reply_bytes);
    self->messages = self->bytes = self->samples = self->stale = self->publish_errors = 0;
    self->acknacks = self->acknack_bytes = self->timestamp_replies = 0;
    self->timestamp_reply_bytes = 0;
    self->pending_count = 0;  /* every ack_due was just handed to Python */
    self->pending_overflow = 0;
    pthread_mutex_unlock(&self->mutex);
    if (!failed && totals) result = Py_BuildValue("(NOOO)", totals, clients, writers, acks);
    else Py_XDECREF(totals);
done:
    Py_XDECREF(clients);
    Py_XDECREF(writers);
    Py_XDECREF(acks);
    return result;
}

/* handle(data, address): try_fast on one datagram as the receive thread would, for tests and fuzzing without
 * a socket; True if it was taken here, False if Python would have it. */
static PyObject *Receiver_handle(Receiver *self, PyObject *args) {
    Py_buffer data;
    PyObject *address;
    if (!PyArg_ParseTuple(args, "y*O", &data, &address)) return NULL;
    struct sockaddr_storage from;
    socklen_t from_len;
    if (parse_address(address, &from, &from_len) < 0) {
        PyBuffer_Release(&data);
        return NULL;
    }
    /* A private copy: try_fast writes the encapsulation header into its buffer. */
    uint8_t *copy = malloc(data.len ? data.len : 1);
    if (copy == NULL) {
        PyBuffer_Release(&data);
        return PyErr_NoMemory();
    }
    memcpy(copy, data.buf, data.len);
    pthread_mutex_lock(&self->mutex);
    int taken = try_fast(self, copy, data.len, &from);
    pthread_mutex_unlock(&self->mutex);
    free(copy);
    PyBuffer_Release(&data);
    return PyBool_FromLong(taken);
}

static PyMethodDef Receiver_methods[] = {
    /* _receive_thread.c */
    {"start", (PyCFunction)Receiver_start, METH_O, "start(notify_fd): read on a thread of its own"},
    {"stop", (PyCFunction)Receiver_stop, METH_NOARGS, NULL},
    {"take", (PyCFunction)Receiver_take, METH_NOARGS, "take() -> [(datagram, address)] for Python"},
    {"pause", (PyCFunction)Receiver_pause, METH_NOARGS, NULL},
    {"resume", (PyCFunction)Receiver_resume, METH_NOARGS, NULL},
    {"handoff_dropped", (PyCFunction)Receiver_handoff_dropped, METH_NOARGS, NULL},
    /* _reader_out.c */
    {"add_reader", (PyCFunction)Receiver_add_reader, METH_VARARGS, NULL},
    {"remove_reader", (PyCFunction)Receiver_remove_reader, METH_O, NULL},
    {"set_reader_client", (PyCFunction)Receiver_set_reader_client, METH_VARARGS, NULL},
    {"reclaim_reader", (PyCFunction)Receiver_reclaim_reader, METH_O, NULL},
    {"set_reader_direct", (PyCFunction)Receiver_set_reader_direct, METH_VARARGS, NULL},
    {"heartbeat_due", (PyCFunction)Receiver_heartbeat_due, METH_O, NULL},
    {"fold_readers", (PyCFunction)Receiver_fold_readers, METH_NOARGS, NULL},
    /* _replier_out.c */
    {"add_replier", (PyCFunction)Receiver_add_replier, METH_VARARGS, NULL},
    {"send_reply", (PyCFunction)Receiver_send_reply, METH_VARARGS, NULL},
    {"replier_sequence", (PyCFunction)Receiver_replier_sequence, METH_O, NULL},
    {"take_expired", (PyCFunction)Receiver_take_expired, METH_NOARGS, NULL},
    {"add_out_best_effort", (PyCFunction)Receiver_add_out_best_effort, METH_VARARGS, NULL},
    {"out_best_effort_next", (PyCFunction)Receiver_out_best_effort_next, METH_VARARGS, NULL},
    {"add_client", (PyCFunction)Receiver_add_client, METH_VARARGS, NULL},
    {"remove_client", (PyCFunction)Receiver_remove_client, METH_O, NULL},
    {"set_client_enabled", (PyCFunction)Receiver_set_client_enabled, METH_VARARGS, NULL},
    {"set_enabled", (PyCFunction)Receiver_set_enabled, METH_O, NULL},
    {"add_stream", (PyCFunction)Receiver_add_stream, METH_VARARGS, NULL},
    {"stream_accept", (PyCFunction)Receiver_stream_accept, METH_VARARGS, NULL},
    {"stream_seq", (PyCFunction)Receiver_stream_seq, METH_VARARGS, NULL},
    {"reliable_state", (PyCFunction)Receiver_reliable_state, METH_VARARGS, NULL},
    {"set_reliable_state", (PyCFunction)Receiver_set_reliable_state, METH_VARARGS, NULL},
    {"add_writer", (PyCFunction)Receiver_add_writer, METH_VARARGS, NULL},
    {"remove_writer", (PyCFunction)Receiver_remove_writer, METH_VARARGS, NULL},
    {"fold", (PyCFunction)Receiver_fold, METH_NOARGS, NULL},
    {"handle", (PyCFunction)Receiver_handle, METH_VARARGS, NULL},
    /* _reliable_out.c */
    {"add_out_stream", (PyCFunction)Receiver_add_out_stream, METH_VARARGS, NULL},
    {"out_acknowledged", (PyCFunction)Receiver_out_acknowledged, METH_VARARGS, NULL},
    {"set_out_state", (PyCFunction)Receiver_set_out_state, METH_VARARGS, NULL},
    {"set_probing", (PyCFunction)Receiver_set_probing, METH_VARARGS, NULL},
    {"out_state", (PyCFunction)Receiver_out_state, METH_VARARGS, NULL},
    {"out_reserve", (PyCFunction)Receiver_out_reserve, METH_VARARGS, NULL},
    {"out_message", (PyCFunction)Receiver_out_message, METH_VARARGS, NULL},
    {"set_out_held", (PyCFunction)Receiver_set_out_held, METH_VARARGS, NULL},
    /* _reliable_in.c */
    {"take_partial", (PyCFunction)Receiver_take_partial, METH_VARARGS, NULL},
    {"put_partial", (PyCFunction)Receiver_put_partial, METH_VARARGS, NULL},
    {"set_room", (PyCFunction)Receiver_set_room, METH_VARARGS, NULL},
    {"set_reassembly_limit", (PyCFunction)Receiver_set_reassembly_limit, METH_O, NULL},
    {"fold_reliable", (PyCFunction)Receiver_fold_reliable, METH_NOARGS, NULL},
    {NULL},
};

static PyTypeObject ReceiverType = {
    PyVarObject_HEAD_INIT(NULL, 0)
    .tp_name = "xrce.agent.engine.compiled._fastpath.Receiver",
    .tp_basicsize = sizeof(Receiver),
    .tp_flags = Py_TPFLAGS_DEFAULT,
    .tp_new = PyType_GenericNew,
    .tp_init = (initproc)Receiver_init,
    .tp_dealloc = (destructor)Receiver_dealloc,
    .tp_methods = Receiver_methods,
};

/* resolve_rcl(): True once rcl_publish_serialized_message is found in an already loaded librcl. */
static PyObject *resolve_rcl(PyObject *module, PyObject *unused) {
    if (rcl_publish_serialized == NULL)
        rcl_publish_serialized = (publish_serialized_fn)loaded_symbol(
            "librcl.so", "rcl_publish_serialized_message");
    return PyBool_FromLong(rcl_publish_serialized != NULL);
}

static PyObject *resolve_readers(PyObject *module, PyObject *unused) {
    return resolve_rcl_readers();
}

static PyMethodDef module_methods[] = {
    {"resolve_rcl", resolve_rcl, METH_NOARGS, NULL},
    {"resolve_readers", resolve_readers, METH_NOARGS,
     "True once rcl's serialized take and message callback are found"},
    {NULL},
};

/* CRC-32 of this folder's C sources, given by setup.py (xrce.agent.engine.compiled.fastpath
 * compares it with them). */
#ifndef XRCE_SOURCE_CRC
#define XRCE_SOURCE_CRC "unknown"
#endif

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "xrce.agent.engine.compiled._fastpath", NULL, -1, module_methods,
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
    if (PyModule_AddStringConstant(m, "SOURCE_CRC", XRCE_SOURCE_CRC) < 0) {
        Py_DECREF(m);
        return NULL;
    }
    return m;
}
