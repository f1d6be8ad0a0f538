/* Reliable input in the compiled receive path: FRAGMENTs of a registered reliable stream, and the
 * client's HEARTBEAT for one (the seams of xrce.agent.engine.datapath._fragment and
 * xrce.agent.engine.liveliness._on_heartbeat).
 *
 * Why: a board's samples longer than its MTU (a TurtleBot3's /odom) arrive as several FRAGMENT
 * messages on its reliable stream, and its HEARTBEATs ask for the stream's ACKNACK; both kept the
 * robot's traffic in Python after in-order WRITE_DATA had moved here (_fastpath.c).
 *
 * The rules are try_fast_reliable's: a message is taken only as the next in order with nothing
 * held out of order in Python, and the stream moves only for what was delivered. A fragment is
 * delivered once its chunk is in the stream's reassembly buffer; the last one only when the
 * message it completes is one WRITE_DATA to a registered writer that publishes, otherwise its
 * datagram goes to Python unchanged and the buffer is as before it. Anything unusual (a fragment
 * that would pass Agent.max_reassembly_bytes or the client's byte budget, a HEARTBEAT that makes
 * the stream skip, a big-endian one) is Python's, which takes the buffer from here first
 * (take_partial) and puts back what it leaves (put_partial): the buffer has one owner at a time.
 */
#include "_fastpath.h"

#include <stdlib.h>

#define KEEP_CAPACITY 65536  /* a finished reassembly keeps at most this much allocated */

void free_reassembly(Stream *s) {
    free(s->frag);
    s->frag = NULL;
    s->frag_len = s->frag_cap = 0;
}

static int reserve(Stream *s, size_t needed, size_t limit) {
    if (needed <= s->frag_cap) return 1;
    size_t capacity = s->frag_cap ? s->frag_cap : 1024;
    while (capacity < needed) capacity *= 2;
    if (capacity > limit) capacity = limit;  /* needed <= limit: checked by the caller */
    uint8_t *grown = realloc(s->frag, capacity);
    if (grown == NULL) return 0;
    s->frag = grown;
    s->frag_cap = capacity;
    return 1;
}

/* The stream handled fragment seq here (stream_delivered), counted as a fragment. */
static void delivered(Receiver *self, Client *c, Stream *s, uint16_t seq, size_t length) {
    stream_delivered(self, c, s, seq, length);
    self->fragments_in++;
}

/* Publish the reassembled message if it is one WRITE_DATA (FORMAT_DATA) to a registered writer:
 * its length exact, or 0 (the sample runs to the end of the message, as the C client writes one
 * longer than 64 KiB). 1 if published. */
static int publish_reassembled(Receiver *self, Client *c, uint8_t *message, size_t total) {
    size_t pos = message[0] < 0x80 ? 8 : 4;
    if (pos + 8 > total || message[pos] != WRITE_DATA ||
        (message[pos + 1] & FORMAT_MASK) != FORMAT_DATA)
        return 0;
    size_t sub_length = message[pos + 2] | (message[pos + 3] << 8);
    if (sub_length == 0) sub_length = total - pos - 4;
    else if (sub_length < 4 || pos + 4 + sub_length != total) return 0;
    Writer *writer = find_writer(c, (uint16_t)(message[pos + 6] << 8 | message[pos + 7]));
    if (writer == NULL) return 0;
    uint8_t *body = message + pos + 4, ids[4];
    memcpy(ids, body, 4);
    body[0] = 0x00, body[1] = 0x01, body[2] = 0x00, body[3] = 0x00;  /* XRCE-WIRE.md §14 */
    serialized_message_t sample = {body, sub_length, sub_length, {0}};
    if (rcl_publish_serialized(writer->publisher, &sample, NULL) != 0) {
        memcpy(body, ids, 4);
        return 0;
    }
    self->samples++;
    writer->samples++;
    writer->sample_bytes += sub_length - 4;
    return 1;
}

/* A datagram of one FRAGMENT, next in order on a registered reliable stream (try_fast_reliable
 * checked both). 1: taken (stored, or the message it completes published); 0: Python's, nothing
 * changed. Python's checks, in its order: the client's byte budget for the datagram
 * (_hold_back), then the reassembly limit (_fragment). */
int try_fast_fragment(Receiver *self, Client *c, Stream *s, uint8_t *data, size_t length,
                      size_t pos, size_t sub_length) {
    if ((int64_t)length > c->room || self->reassembly_limit == 0) return 0;
    size_t header = s->frag_len ? 0 : pos;  /* a new message starts with this one's header */
    size_t before = s->frag_len, total = before + header + sub_length;
    if (total > self->reassembly_limit || !reserve(s, total, self->reassembly_limit)) return 0;
    if (header) memcpy(s->frag, data, header);
    memcpy(s->frag + before + header, data + pos + 4, sub_length);
    uint16_t seq = data[2] | (data[3] << 8);
    if (data[pos + 1] & FLAG_LAST_FRAGMENT) {
        if (!publish_reassembled(self, c, s->frag, total)) {
            s->frag_len = before;  /* as it was: Python appends this chunk itself */
            if (before == 0) free_reassembly(s);
            return 0;
        }
        /* Python charges each chunk and gives the whole buffer back when it is done */
        c->frag_charged -= (int64_t)before;
        c->room += (int64_t)before;
        s->frag_len = 0;
        if (s->frag_cap > KEEP_CAPACITY) free_reassembly(s);
    } else {
        s->frag_len = total;
        c->frag_charged += (int64_t)(header + sub_length);
        c->room -= (int64_t)(header + sub_length);
    }
    delivered(self, c, s, seq, length);
    return 1;
}

/* A message on stream 0 holding one little-endian HEARTBEAT for a registered reliable stream that
 * Python holds nothing out of order for: noted and answered here as _on_heartbeat would (the
 * ACKNACK at once, every message announced and not handled named missing). A HEARTBEAT that makes
 * the stream skip messages is Python's. */
int try_fast_heartbeat(Receiver *self, Client *c, const uint8_t *data, size_t length) {
    size_t pos = data[0] < 0x80 ? 8 : 4;
    if (length != pos + 9 || data[pos] != HEARTBEAT || !(data[pos + 1] & 0x01) ||
        (data[pos + 2] | data[pos + 3] << 8) != 5)
        return 0;
    uint16_t first_unacked = data[pos + 4] | data[pos + 5] << 8;
    uint16_t last_unacked = data[pos + 6] | data[pos + 7] << 8;
    Stream *s = find_stream(c, data[pos + 8]);
    if (s == NULL || !s->reliable || s->last_announced != s->last_seq ||
        seq_less((uint16_t)(s->last_seq + 1), first_unacked))
        return 0;
    uint16_t announced = seq_less(s->last_announced, last_unacked) ? last_unacked
                                                                   : s->last_announced;
    uint16_t bitmap = 0, first = (uint16_t)(s->last_seq + 1);
    for (int i = 0; i < 16 && !seq_less(announced, (uint16_t)(first + i)); i++)
        bitmap |= (uint16_t)(1u << i);
    uint16_t kept = s->last_announced;
    s->last_announced = announced;
    if (!send_stream_acknack(self, c, s, bitmap)) {
        s->last_announced = kept;
        return 0;
    }
    count_message(self, c, length);
    return 1;
}

/* ----------------------------------------------------------------------------- Python side */

/* take_partial(handle, stream_id) -> the reassembly buffer's bytes, or None when there is none;
 * from then on Python holds it (ClientProxy.reassembly) until it puts back what is left. */
PyObject *Receiver_take_partial(Receiver *self, PyObject *args) {
    long handle;
    int stream_id;
    if (!PyArg_ParseTuple(args, "li", &handle, &stream_id)) return NULL;
    PyObject *result = NULL;
    pthread_mutex_lock(&self->mutex);
    Client *c = client_by_handle(self, handle);
    Stream *s = c ? find_stream(c, (uint8_t)stream_id) : NULL;
    if (s && s->frag_len) {
        result = PyBytes_FromStringAndSize((const char *)s->frag, (Py_ssize_t)s->frag_len);
        if (result) {  /* the bytes stay charged to the client: only their holder changes */
            s->frag_len = 0;
            if (s->frag_cap > KEEP_CAPACITY) free_reassembly(s);
        }
    }
    pthread_mutex_unlock(&self->mutex);
    if (result == NULL && PyErr_Occurred()) return NULL;
    if (result == NULL) Py_RETURN_NONE;
    return result;
}

/* put_partial(handle, stream_id, buffer) -> True if the stream is registered and now holds it (a
 * reassembly Python started or continued and did not finish; already charged by Python). */
PyObject *Receiver_put_partial(Receiver *self, PyObject *args) {
    long handle;
    int stream_id;
    Py_buffer buffer;
    if (!PyArg_ParseTuple(args, "liy*", &handle, &stream_id, &buffer)) return NULL;
    int kept = 0;
    pthread_mutex_lock(&self->mutex);
    Client *c = client_by_handle(self, handle);
    Stream *s = c ? find_stream(c, (uint8_t)stream_id) : NULL;
    size_t size = (size_t)buffer.len;
    if (s && s->reliable && s->frag_len == 0 && size &&
        reserve(s, size, size > self->reassembly_limit ? size : self->reassembly_limit)) {
        memcpy(s->frag, buffer.buf, size);
        s->frag_len = size;
        kept = 1;
    }
    pthread_mutex_unlock(&self->mutex);
    PyBuffer_Release(&buffer);
    return PyBool_FromLong(kept);
}

/* set_room(handle, bytes): what the client's byte budget leaves, as Python sees it now (its
 * counters include what this module held at the last fold). */
PyObject *Receiver_set_room(Receiver *self, PyObject *args) {
    long handle;
    long long room;
    if (!PyArg_ParseTuple(args, "lL", &handle, &room)) return NULL;
    pthread_mutex_lock(&self->mutex);
    Client *c = client_by_handle(self, handle);
    if (c) c->room = room - c->frag_charged;  /* what is not folded yet is not in Python's */
    pthread_mutex_unlock(&self->mutex);
    Py_RETURN_NONE;
}

PyObject *Receiver_set_reassembly_limit(Receiver *self, PyObject *arg) {
    Py_ssize_t limit = PyLong_AsSsize_t(arg);
    if (limit < 0) {
        if (!PyErr_Occurred()) PyErr_SetString(PyExc_ValueError, "negative reassembly limit");
        return NULL;
    }
    pthread_mutex_lock(&self->mutex);
    self->reassembly_limit = (size_t)limit;
    pthread_mutex_unlock(&self->mutex);
    Py_RETURN_NONE;
}

/* fold_reliable() -> (fragments taken, [(handle, bytes of reassembly to charge)]) since the last
 * call, reset here; None when there is nothing (the common wake-up: no list to build). */
PyObject *Receiver_fold_reliable(Receiver *self, PyObject *unused) {
    pthread_mutex_lock(&self->mutex);
    int any = self->fragments_in != 0;
    for (Client *c = self->clients; c && !any; c = c->next) any = c->frag_charged != 0;
    if (!any) {
        pthread_mutex_unlock(&self->mutex);
        Py_RETURN_NONE;
    }
    PyObject *charges = PyList_New(0);
    int failed = charges == NULL;
    for (Client *c = self->clients; c && !failed; c = c->next) {
        if (!c->frag_charged) continue;
        PyObject *row = Py_BuildValue("(lL)", c->handle, (long long)c->frag_charged);
        failed = row == NULL || PyList_Append(charges, row) < 0;
        Py_XDECREF(row);
        if (!failed) c->frag_charged = 0;
    }
    unsigned long long fragments = self->fragments_in;
    if (!failed) self->fragments_in = 0;
    pthread_mutex_unlock(&self->mutex);
    if (failed) {
        Py_XDECREF(charges);
        return NULL;
    }
    return Py_BuildValue("(KN)", fragments, charges);
}
