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
 * One owner per number: the acknowledged point lives here (Python reads and moves it through
 * out_acknowledged and set_out_state:
 * xrce.agent.engine.compiled_streams.CompiledOutputStream); last_sent is Python's, written here
 * before the message goes out, read here. The history slots this frees are released by Python
 * when it next uses the stream (CompiledOutputStream.release), under the engine's lock, with their
 * bytes' charge to the client's budget.
 */
#include "_fastpath.h"

#include <stdlib.h>

static OutStream *find_out_stream(Client *c, uint8_t stream_id) {
    for (OutStream *o = c->out_streams; o; o = o->next)
        if (o->stream_id == stream_id) return o;
    return NULL;
}

void free_out_streams(Client *c) {
    for (OutStream *o = c->out_streams, *n; o; o = n) { n = o->next; free(o); }
    c->out_streams = NULL;
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
    if (seq_less(o->last_acknowledged, acknowledged)) o->last_acknowledged = acknowledged;
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
        o->stream_id = (uint8_t)stream_id;
        o->next = c->out_streams;
        c->out_streams = o;
    }
    if (o) {
        o->history = (uint16_t)history;
        o->last_sent = (uint16_t)last_sent;
        o->last_acknowledged = (uint16_t)acknowledged;
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
    if (o && acknowledged >= 0) o->last_acknowledged = (uint16_t)acknowledged;
    pthread_mutex_unlock(&self->mutex);
    return PyBool_FromLong(o != NULL);
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
