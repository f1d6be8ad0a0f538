/* The client's ACKNACKs for the agent's reliable output streams in the compiled receive path (the
 * seam of xrce.agent.engine.liveliness._on_acknack).
 *
 * Why: a board acknowledges every message the agent sends it on a reliable stream (a TurtleBot3's
 * cmd_vel, 30 a second); each ACKNACK was a datagram through Python's whole receive path that
 * only moved the stream's acknowledged point.
 *
 * Only such an ACKNACK is taken here: little-endian, alone in its message, no NACK bit (nothing
 * to retransmit), not acknowledging more than was sent, for a registered stream whose window is
 * not full, while Python times no HEARTBEAT (probing). A full window is where Python keeps a
 * STATUS waiting (ClientProxy.out_pending) or a reader blocked (blocked_readers): both only ever
 * wait on a full window, and a full window's acknowledged point moves only through Python, so the
 * ACKNACK that frees its room is always Python's, which sends what waits. Everything else reaches
 * Python unchanged.
 *
 * One owner per number: both of the stream's numbers live here (Python reads and moves them
 * through out_acknowledged, out_reserve and set_out_state:
 * xrce.agent.engine.compiled.streams.CompiledOutputStream), since the receive thread sends a
 * reader's DATA on the stream too (_reader_out.c). The history is split by who sent the message:
 * the messages sent here are kept here (slots) and freed as the acknowledged point passes them;
 * Python's stay Python's, released when it next uses the stream (CompiledOutputStream.release),
 * under the engine's lock, with their bytes' charge to the client's budget.
 */
#include "_fastpath.h"

#include <stdlib.h>

OutStream *find_out_stream(Client *c, uint8_t stream_id) {
    for (OutStream *o = c->out_streams; o; o = o->next)
        if (o->stream_id == stream_id) return o;
    return NULL;
}

static void free_slots(OutStream *o) {
    if (o->slots == NULL) return;
    for (unsigned i = 0; i < o->history; i++) {
        free(o->slots[i]);
        o->slots[i] = NULL;
    }
}

void free_out_streams(Client *c) {
    for (OutStream *o = c->out_streams, *n; o; o = n) {
        n = o->next;
        free_slots(o);
        free(o->slots);
        free(o->lengths);
        free(o);
    }
    c->out_streams = NULL;
    for (OutBestEffort *b = c->out_best_effort, *n; b; b = n) { n = b->next; free(b); }
    c->out_best_effort = NULL;
}

/* The acknowledged point moves to ``acknowledged``: the messages this module kept up to it are
 * freed (Python frees its own, CompiledOutputStream._release). A point behind the current one
 * (the stream was reset) frees everything kept. */
void out_stream_release(OutStream *o, uint16_t acknowledged) {
    if (!seq_less(o->last_acknowledged, acknowledged)) {
        if (acknowledged != o->last_acknowledged) free_slots(o);
        o->last_acknowledged = acknowledged;
        return;
    }
    while (o->last_acknowledged != acknowledged) {
        o->last_acknowledged++;
        unsigned slot = o->last_acknowledged & (o->history - 1);
        free(o->slots[slot]);
        o->slots[slot] = NULL;
    }
}

/* A message on stream 0 holding one ACKNACK as the header comment says: the acknowledged point
 * moves here as OutputReliableStream.on_acknack moves it. 1 if taken. */
int try_fast_acknack(Receiver *self, Client *c, const uint8_t *data, size_t length) {
    size_t pos = data[0] < 0x80 ? 8 : 4;
    if (length != pos + 9 || data[pos] != ACKNACK || !(data[pos + 1] & 0x01) ||
        (data[pos + 2] | data[pos + 3] << 8) != 5 || c->probing)
        return 0;
    if (data[pos + 6] | data[pos + 7]) return 0;  /* a NACK: retransmissions are Python's */
    OutStream *o = find_out_stream(c, data[pos + 8]);
    if (o == NULL || (uint16_t)(o->last_sent - o->last_acknowledged) >= o->history) return 0;
    uint16_t first_unacked = data[pos + 4] | data[pos + 5] << 8;
    if (seq_less((uint16_t)(o->last_sent + 1), first_unacked))
        return 0;  /* acknowledges what was never sent: Python ignores it */
    uint16_t acknowledged = (uint16_t)(first_unacked - 1);
    if (seq_less(o->last_acknowledged, acknowledged)) out_stream_release(o, acknowledged);
    count_message(self, c, length);
    return 1;
}

/* ----------------------------------------------------------------------------- Python side */

/* add_out_stream(handle, stream_id, history, last_sent, last_acknowledged) -> True if the client
 * is registered (the stream is then, in that state). */
PyObject *Receiver_add_out_stream(Receiver *self, PyObject *args) {
    long handle;
    int stream_id, history, last_sent, acknowledged;
    if (!PyArg_ParseTuple(args, "liiii", &handle, &stream_id, &history, &last_sent, &acknowledged))
        return NULL;
    if (history <= 0 || history > 0x8000 || (history & (history - 1))) {
        PyErr_SetString(PyExc_ValueError, "history must be a power of two");
        return NULL;
    }
    pthread_mutex_lock(&self->mutex);
    Client *c = client_by_handle(self, handle);
    OutStream *o = c ? find_out_stream(c, (uint8_t)stream_id) : NULL;
    if (c && o == NULL && (o = calloc(1, sizeof *o)) != NULL) {
        o->slots = calloc((size_t)history, sizeof *o->slots);
        o->lengths = calloc((size_t)history, sizeof *o->lengths);
        if (o->slots == NULL || o->lengths == NULL) {
            free(o->slots);
            free(o->lengths);
            free(o);
            o = NULL;
        } else {
            o->stream_id = (uint8_t)stream_id;
            o->history = (uint16_t)history;
            o->next = c->out_streams;
            c->out_streams = o;
        }
    }
    if (o && o->history == history) {
        free_slots(o);
        o->last_sent = (uint16_t)last_sent;
        o->last_acknowledged = (uint16_t)acknowledged;
    } else if (o) {
        o = NULL;  /* registered with another window: Python keeps this stream */
        c = NULL;
    }
    pthread_mutex_unlock(&self->mutex);
    if (c && o == NULL) return PyErr_NoMemory();
    return PyBool_FromLong(o != NULL);
}

/* out_acknowledged(handle, stream_id) -> the stream's acknowledged point, or None. */
PyObject *Receiver_out_acknowledged(Receiver *self, PyObject *args) {
    long handle;
    int stream_id;
    if (!PyArg_ParseTuple(args, "li", &handle, &stream_id)) return NULL;
    long acknowledged = -1;
    pthread_mutex_lock(&self->mutex);
    Client *c = client_by_handle(self, handle);
    OutStream *o = c ? find_out_stream(c, (uint8_t)stream_id) : NULL;
    if (o) acknowledged = o->last_acknowledged;
    pthread_mutex_unlock(&self->mutex);
    if (acknowledged < 0) Py_RETURN_NONE;
    return PyLong_FromLong(acknowledged);
}

/* set_out_state(handle, stream_id, last_sent, last_acknowledged): Python moved them (-1: that
 * one unchanged). True if the stream is registered. */
PyObject *Receiver_set_out_state(Receiver *self, PyObject *args) {
    long handle;
    int stream_id, last_sent, acknowledged;
    if (!PyArg_ParseTuple(args, "liii", &handle, &stream_id, &last_sent, &acknowledged))
        return NULL;
    pthread_mutex_lock(&self->mutex);
    Client *c = client_by_handle(self, handle);
    OutStream *o = c ? find_out_stream(c, (uint8_t)stream_id) : NULL;
    if (o && last_sent >= 0) o->last_sent = (uint16_t)last_sent;
    if (o && acknowledged >= 0) out_stream_release(o, (uint16_t)acknowledged);
    pthread_mutex_unlock(&self->mutex);
    return PyBool_FromLong(o != NULL);
}

/* out_state(handle, stream_id) -> (last_sent, last_acknowledged), or None. */
PyObject *Receiver_out_state(Receiver *self, PyObject *args) {
    long handle;
    int stream_id;
    if (!PyArg_ParseTuple(args, "li", &handle, &stream_id)) return NULL;
    long sent = -1, acknowledged = -1;
    pthread_mutex_lock(&self->mutex);
    Client *c = client_by_handle(self, handle);
    OutStream *o = c ? find_out_stream(c, (uint8_t)stream_id) : NULL;
    if (o) {
        sent = o->last_sent;
        acknowledged = o->last_acknowledged;
    }
    pthread_mutex_unlock(&self->mutex);
    if (sent < 0) Py_RETURN_NONE;
    return Py_BuildValue("(ll)", sent, acknowledged);
}

/* out_reserve(handle, stream_id) -> the sequence number Python's next message on the stream
 * carries, taken now (the receive thread may send on the stream too), or None while the window
 * is full. */
PyObject *Receiver_out_reserve(Receiver *self, PyObject *args) {
    long handle;
    int stream_id;
    if (!PyArg_ParseTuple(args, "li", &handle, &stream_id)) return NULL;
    long seq = -1;
    pthread_mutex_lock(&self->mutex);
    Client *c = client_by_handle(self, handle);
    OutStream *o = c ? find_out_stream(c, (uint8_t)stream_id) : NULL;
    if (o && (uint16_t)(o->last_sent - o->last_acknowledged) < o->history) {
        seq = (uint16_t)(o->last_sent + 1);
        o->last_sent = (uint16_t)seq;
        unsigned slot = (unsigned)seq & (o->history - 1);
        free(o->slots[slot]);  /* (acknowledged long ago: freed already) */
        o->slots[slot] = NULL;
    }
    pthread_mutex_unlock(&self->mutex);
    if (seq < 0) Py_RETURN_NONE;
    return PyLong_FromLong(seq);
}

/* out_message(handle, stream_id, seq) -> the message sent here with that sequence number and
 * not yet acknowledged, or None (Python's own, or acknowledged). */
PyObject *Receiver_out_message(Receiver *self, PyObject *args) {
    long handle;
    int stream_id, seq;
    if (!PyArg_ParseTuple(args, "lii", &handle, &stream_id, &seq)) return NULL;
    PyObject *message = NULL;
    pthread_mutex_lock(&self->mutex);
    Client *c = client_by_handle(self, handle);
    OutStream *o = c ? find_out_stream(c, (uint8_t)stream_id) : NULL;
    if (o && seq_less(o->last_acknowledged, (uint16_t)seq) &&
        !seq_less(o->last_sent, (uint16_t)seq)) {
        unsigned slot = (unsigned)seq & (o->history - 1);
        if (o->slots[slot])
            message = PyBytes_FromStringAndSize((const char *)o->slots[slot], o->lengths[slot]);
    }
    pthread_mutex_unlock(&self->mutex);
    if (message == NULL && PyErr_Occurred()) return NULL;
    if (message == NULL) Py_RETURN_NONE;
    return message;
}

/* set_out_held(handle, stream_id, held): Python has output waiting for the stream's window. */
PyObject *Receiver_set_out_held(Receiver *self, PyObject *args) {
    long handle;
    int stream_id, held;
    if (!PyArg_ParseTuple(args, "lip", &handle, &stream_id, &held)) return NULL;
    pthread_mutex_lock(&self->mutex);
    Client *c = client_by_handle(self, handle);
    OutStream *o = c ? find_out_stream(c, (uint8_t)stream_id) : NULL;
    if (o) o->held = held;
    pthread_mutex_unlock(&self->mutex);
    Py_RETURN_NONE;
}

/* set_probing(handle, probing): Python sent a HEARTBEAT and times the ACKNACK answering it. */
PyObject *Receiver_set_probing(Receiver *self, PyObject *args) {
    long handle;
    int probing;
    if (!PyArg_ParseTuple(args, "lp", &handle, &probing)) return NULL;
    pthread_mutex_lock(&self->mutex);
    Client *c = client_by_handle(self, handle);
    if (c) c->probing = probing;
    pthread_mutex_unlock(&self->mutex);
    Py_RETURN_NONE;
}
