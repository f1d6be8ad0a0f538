/* The compiled path's own receive thread: it owns the UDP socket's reads, so a board's steady
 * traffic (samples, fragments, HEARTBEATs, ACKNACKs, TIMESTAMPs: what try_fast takes) never wakes
 * the interpreter. What try_fast leaves goes, in arrival order, into a bounded hand-off that
 * Python takes on the loop's thread when an eventfd wakes it (xrce.agent.engine.compiled.fastpath).
 *
 * Order: once a datagram is handed to Python, every later one is too until Python has handled all
 * it took and resumes this thread (Receiver.resume); Python also pauses it around its own timed
 * work. So C never takes a datagram while Python still holds an earlier one or is deciding which
 * clients C may serve: the same order, and the same datagrams taken, as one thread reading.
 *
 * Back-pressure: a full hand-off stops the reading, so the kernel's socket buffer, not this
 * thread's memory, is what a flood fills (as when the loop read the socket itself).
 *
 * This thread never takes the GIL; Python's calls into the Receiver take its mutex. */
#include "_fastpath.h"

#include <poll.h>
#include <signal.h>
#include <sys/eventfd.h>

#define HANDOFF_COUNT 1024            /* datagrams waiting for Python, at most */
#define HANDOFF_BYTES (4 << 20)       /* and their bytes */

void wake_python(Receiver *self) {
    /* Called locked. One eventfd write per hand-off Python has not yet taken. */
    if (self->notified) return;
    self->notified = 1;
    uint64_t one = 1;
    ssize_t written = write(self->notify_fd, &one, sizeof one);
    (void)written;  /* EAGAIN only when the counter is full: Python is already woken */
}

/* Append one datagram (reader_token 0) or one reader's sample for Python; 0 when the hand-off is
 * full (the caller stops reading). */
int handoff_append(Receiver *self, long reader_token, const uint8_t *data, size_t length,
                   const struct sockaddr_storage *from, socklen_t from_len) {
    if (self->handoff_count >= HANDOFF_COUNT || self->handoff_bytes + length > HANDOFF_BYTES)
        return 0;
    Handed *item = malloc(sizeof *item + (length ? length : 1));
    if (item == NULL) return 0;
    item->next = NULL;
    item->reader_token = reader_token;
    item->length = length;
    if (from != NULL) memcpy(&item->from, from, from_len);
    item->from_len = from_len;
    memcpy(item->data, data, length);
    if (self->handoff_tail) self->handoff_tail->next = item;
    else self->handoff_head = item;
    self->handoff_tail = item;
    self->handoff_count++;
    self->handoff_bytes += length;
    return 1;
}

static void *receive_loop(void *arg) {
    Receiver *self = arg;
    sigset_t all;
    sigfillset(&all);  /* signals stay the main thread's (Python's handlers run there) */
    pthread_sigmask(SIG_BLOCK, &all, NULL);
    struct pollfd fds[3] = {{self->sock, POLLIN, 0}, {self->control_fd, POLLIN, 0},
                            {self->samples_fd, POLLIN, 0}};
    for (;;) {
        pthread_mutex_lock(&self->mutex);
        int full = self->handoff_count >= HANDOFF_COUNT || self->handoff_bytes >= HANDOFF_BYTES;
        int stopping = self->stopping;
        pthread_mutex_unlock(&self->mutex);
        if (stopping) break;
        fds[0].events = full ? 0 : POLLIN;  /* full: wait for Python's take (it writes control_fd) */
        if (poll(fds, 3, -1) < 0 && errno != EINTR) break;
        if (fds[2].revents) {  /* a reader's samples (_reader_out.c) */
            uint64_t value;
            ssize_t got = read(self->samples_fd, &value, sizeof value);
            (void)got;
            pthread_mutex_lock(&self->mutex);
            deliver_samples(self);
            pthread_mutex_unlock(&self->mutex);
        }
        if (fds[1].revents) {
            uint64_t value;
            ssize_t got = read(self->control_fd, &value, sizeof value);
            (void)got;
            continue;  /* stopping, or room in the hand-off again: look again */
        }
        if (!(fds[0].revents & (POLLIN | POLLERR))) continue;
        int count = recvmmsg(self->sock, self->messages_hdr, BATCH, MSG_DONTWAIT, NULL);
        if (count <= 0) {
            /* EAGAIN, or an ICMP error of an earlier send (port unreachable after a client went
             * away), which reading clears: Python's read logged it at debug level and went on. */
            continue;
        }
        pthread_mutex_lock(&self->mutex);
        int handled = 0, handed = 0;
        for (int i = 0; i < count; i++) {
            uint8_t *data = self->buffers[i];
            size_t length = self->messages_hdr[i].msg_len;
            if (!handed && self->paused == 0 && self->handoff_count == 0 &&
                try_fast(self, data, length, &self->sources[i])) {
                handled++;
                continue;
            }
            if (!handoff_append(self, 0, data, length, &self->sources[i],
                          self->messages_hdr[i].msg_hdr.msg_namelen)) {
                /* the hand-off filled within this batch (or malloc failed): dropped and
                 * counted, as the socket's own buffer drops what overflows it */
                self->handoff_dropped++;
                continue;
            }
            handed = 1;
        }
        if (handled && !handed && self->enabled && send_due_acknacks(self) > 0)
            handed = 1;  /* a stream owes an ACKNACK only Python can write: fold soon */
        if (handed || self->handoff_count) wake_python(self);
        pthread_mutex_unlock(&self->mutex);
        for (int i = 0; i < count; i++)
            self->messages_hdr[i].msg_hdr.msg_namelen = sizeof self->sources[i];
    }
    return NULL;
}

/* start(notify_fd): read the socket on a thread of its own from now on; notify_fd (an eventfd
 * of Python's) is written when the hand-off has something, or a fold is wanted. */
PyObject *Receiver_start(Receiver *self, PyObject *arg) {
    int fd = PyLong_AsLong(arg);
    if (fd < 0 && PyErr_Occurred()) return NULL;
    if (self->running) {
        PyErr_SetString(PyExc_RuntimeError, "the receive thread is already running");
        return NULL;
    }
    if (map_buffers(self) < 0) return PyErr_SetFromErrno(PyExc_OSError);
    self->control_fd = eventfd(0, EFD_NONBLOCK | EFD_CLOEXEC);
    if (self->control_fd < 0) return PyErr_SetFromErrno(PyExc_OSError);
    if (self->samples_fd < 0) self->samples_fd = eventfd(0, EFD_NONBLOCK | EFD_CLOEXEC);
    if (self->samples_fd < 0) {
        close(self->control_fd);
        self->control_fd = -1;
        return PyErr_SetFromErrno(PyExc_OSError);
    }
    self->notify_fd = fd;
    self->stopping = 0;
    int error = pthread_create(&self->thread, NULL, receive_loop, self);
    if (error) {
        close(self->control_fd);
        self->control_fd = -1;
        errno = error;
        return PyErr_SetFromErrno(PyExc_OSError);
    }
    self->running = 1;
    Py_RETURN_NONE;
}

/* stop(): end the thread and wait for it (GIL released); what it had not handed over is dropped
 * with the link. Idempotent. */
void stop_receive_thread(Receiver *self) {
    if (!self->running) return;
    pthread_mutex_lock(&self->mutex);
    self->stopping = 1;
    pthread_mutex_unlock(&self->mutex);
    uint64_t one = 1;
    ssize_t written = write(self->control_fd, &one, sizeof one);
    (void)written;
    pthread_join(self->thread, NULL);
    self->running = 0;
    close(self->control_fd);
    self->control_fd = -1;
    for (Handed *item = self->handoff_head, *next; item; item = next) {
        next = item->next;
        free(item);
    }
    self->handoff_head = self->handoff_tail = NULL;
    self->handoff_count = 0;
    self->handoff_bytes = 0;
}

PyObject *Receiver_stop(Receiver *self, PyObject *unused) {
    Py_BEGIN_ALLOW_THREADS
    stop_receive_thread(self);
    Py_END_ALLOW_THREADS
    Py_RETURN_NONE;
}

/* take() -> [(datagram, address) or (sample, reader token)]: what the thread handed over, in
 * arrival order. */
PyObject *Receiver_take(Receiver *self, PyObject *unused) {
    pthread_mutex_lock(&self->mutex);
    Handed *items = self->handoff_head;
    int was_full = self->handoff_count >= HANDOFF_COUNT || self->handoff_bytes >= HANDOFF_BYTES;
    Py_ssize_t count = self->handoff_count;
    self->handoff_head = self->handoff_tail = NULL;
    self->handoff_count = 0;
    self->handoff_bytes = 0;
    self->notified = 0;
    pthread_mutex_unlock(&self->mutex);
    if (was_full) {  /* the thread stopped reading: it may read again */
        uint64_t one = 1;
        ssize_t written = write(self->control_fd, &one, sizeof one);
        (void)written;
    }
    PyObject *out = PyList_New(count);
    Py_ssize_t i = 0;
    for (Handed *item = items, *next; item; item = next, i++) {
        next = item->next;
        if (out != NULL) {
            /* a datagram with its source address, or a reader's sample with its token */
            PyObject *second = item->reader_token ? PyLong_FromLong(item->reader_token)
                                                  : address_tuple(&item->from);
            PyObject *row = second ? Py_BuildValue("(y#N)", item->data,
                                                   (Py_ssize_t)item->length, second) : NULL;
            if (row == NULL) Py_CLEAR(out);
            else PyList_SET_ITEM(out, i, row);
        }
        free(item);
    }
    return out;
}

/* pause(): until the matching resume(), every datagram goes to Python (its engine is deciding
 * something C reads: which clients are eligible, a stream's state). */
PyObject *Receiver_pause(Receiver *self, PyObject *unused) {
    pthread_mutex_lock(&self->mutex);
    self->paused++;
    pthread_mutex_unlock(&self->mutex);
    Py_RETURN_NONE;
}

/* resume() -> True when nothing waits for Python, False when the thread has handed over more
 * since the last take() (Python is woken for it: the eventfd is written). */
PyObject *Receiver_resume(Receiver *self, PyObject *unused) {
    pthread_mutex_lock(&self->mutex);
    if (self->paused > 0) self->paused--;
    int idle = self->handoff_count == 0;
    pthread_mutex_unlock(&self->mutex);
    return PyBool_FromLong(idle);
}

/* handoff_dropped() -> datagrams read but not handed over since the last call (no memory). */
PyObject *Receiver_handoff_dropped(Receiver *self, PyObject *unused) {
    pthread_mutex_lock(&self->mutex);
    unsigned long long dropped = self->handoff_dropped;
    self->handoff_dropped = 0;
    pthread_mutex_unlock(&self->mutex);
    return PyLong_FromUnsignedLongLong(dropped);
}
