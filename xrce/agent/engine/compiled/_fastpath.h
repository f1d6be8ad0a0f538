/* What the compiled receive path's C files share (_fastpath.c: the read, best-effort and in-order
 * WRITE_DATA, registration; _reliable_in.c: FRAGMENTs and HEARTBEATs of reliable input): the
 * tables Python registers into and the helpers that walk them. Every function here is called with
 * the Receiver's mutex held. */
#ifndef XRCE_FASTPATH_H
#define XRCE_FASTPATH_H

#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include <arpa/inet.h>
#include <dlfcn.h>
#include <errno.h>
#include <netinet/in.h>
#include <pthread.h>
#include <stdbool.h>
#include <stdint.h>
#include <string.h>
#include <sys/mman.h>
#include <sys/socket.h>
#include <time.h>
#include <unistd.h>

#define BATCH 64            /* datagrams per recvmmsg */
#define MAX_DATAGRAM 65536  /* UDP's limit: nothing is ever truncated */
#define WRITE_DATA 0x07
#define FORMAT_MASK 0x0E
#define FORMAT_DATA 0x00
#define ACKNACK 0x0A
#define HEARTBEAT 0x0B
#define FRAGMENT 0x0D
#define TIMESTAMP 0x0E
#define TIMESTAMP_REPLY 0x0F
#define FLAG_LAST_FRAGMENT 0x02
#define PENDING_ACKS 64     /* reliable streams owing an ACKNACK remembered for a batch's sweep */

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
extern publish_serialized_fn rcl_publish_serialized;  /* _fastpath.c: resolve_rcl */
typedef void (*reset_error_fn)(void);  /* rcutils_reset_error */

typedef struct Writer {
    struct Writer *next;
    uint16_t object_id;
    const void *publisher;  /* rcl_publisher_t *, valid while registered */
    uint64_t samples, sample_bytes;
} Writer;

typedef struct Stream {
    struct Stream *next;
    uint8_t stream_id;
    uint16_t last_seq;  /* the last accepted (best-effort) or handled (reliable) sequence number */
    /* Reliable streams only: the highest sequence number the client is known to have sent
     * (xrce.wire.streams.InputReliableStream.last_announced), and whether a message was handled here
     * since the last fold (Python then sends the stream's ACKNACK). */
    int reliable, ack_due;
    uint16_t last_announced;
    /* Reliable streams only: the message being put together from FRAGMENTs (_reliable_in.c), as
     * Python's ClientProxy.reassembly holds it: the first fragment's message header, then the
     * chunks. The one copy of it while the stream is registered: Python takes it for the
     * fragments it handles itself and puts back what is left (take_partial, put_partial). */
    uint8_t *frag;
    size_t frag_len, frag_cap;
} Stream;

/* The agent's reliable output stream to a client (xrce.wire.streams.OutputReliableStream), as far as
 * an ACKNACK needs it (_reliable_out.c): Python writes last_sent (its only writer, under the
 * engine's lock) and frees the history; the acknowledged point lives only here. */
typedef struct OutStream {
    struct OutStream *next;
    uint8_t stream_id;
    uint16_t history;  /* the window, a power of two */
    uint16_t last_sent, last_acknowledged;
    /* The messages this module sent on the stream itself (_reader_out.c: DATA for a reader), kept
     * until acknowledged for a retransmission Python asks for (out_message); NULL in a slot
     * whose message is Python's. */
    uint8_t **slots;
    uint16_t *lengths;
    /* Python has output waiting for this stream's window (ClientProxy.out_pending): it goes
     * first, so nothing is sent here meanwhile. */
    int held;
} OutStream;

/* An agent best-effort output stream whose sequence numbers live here once a reader may be
 * served on it (xrce.agent.engine.compiled.streams.CompiledOutputBestEffort). */
typedef struct OutBestEffort {
    struct OutBestEffort *next;
    uint8_t stream_id;
    uint16_t last_sent;
} OutBestEffort;

/* A datareader whose samples reach this module first (_reader_out.c): rmw signals each through
 * the subscription's on-new-message callback (signalled, the only field written without the
 * mutex), the receive thread takes them. With request_id set (Python's set_reader_direct, for a
 * READ_DATA without limits and nothing queued in Python), a sample goes out here as a DATA on
 * stream_id; otherwise, or when it cannot (window full, too long, client not enabled), it is
 * handed to Python and direct delivery stops until Python sets it again. */
/* A board's replier served here (_replier_out.c): what a Reader of a service needs beyond a
 * datareader's. Requests go to the board under an identity of this replier's; the DDS request
 * each answers (rmw_request_id_t) waits here until its reply comes back or it expires. */
#define PENDING_REQUESTS 256  /* a power of two: requests of one replier awaiting the board */
typedef struct PendingRequest {
    uint64_t sequence;    /* the identity's sequence number; 0: answered or expired */
    int64_t deadline_ns;  /* CLOCK_MONOTONIC; 0: waits however long (an action's get_result) */
    uint64_t header[3];   /* rmw_request_id_t: the requester's writer GUID, its sequence number */
} PendingRequest;

typedef struct ServicePart {
    const void *request_type, *response_type;  /* rosidl message type supports */
    void *(*create_request)(void);
    void (*destroy_request)(void *);
    void *(*create_response)(void);
    void (*destroy_response)(void *);
    uint8_t prefix[16];   /* the identities' GUID: guidPrefix, entityKey, entityKind */
    uint64_t sequence;    /* the last identity given, here or to Python (replier_sequence) */
    int64_t timeout_ns;   /* 0: requests never expire */
    unsigned head, count; /* the pending ring, oldest first */
    PendingRequest pending[PENDING_REQUESTS];
} ServicePart;

typedef void (*event_callback_fn)(const void *user_data, size_t count);
typedef int (*set_event_callback_fn)(const void *entity, event_callback_fn callback,
                                     const void *user_data);

typedef struct Reader {
    struct Reader *next;
    struct Client *client;
    struct Receiver *receiver;
    uint16_t object_id;
    const void *subscription;  /* rcl_subscription_t *, valid while registered */
    long token;                /* how Python names it in a hand-over */
    int request_id;            /* -1: every sample is Python's */
    uint8_t stream_id;
    volatile int signalled;    /* rmw said a sample is waiting (atomic builtins) */
    uint64_t samples, sample_bytes, messages, bytes;  /* sent here since the last fold */
    /* A replier's (subscription is then its rcl_service_t *), NULL for a datareader; and the
     * rcl function that points the entity's new-data callback. */
    ServicePart *service;
    set_event_callback_fn set_callback;
} Reader;

typedef struct Client {
    struct Client *next;
    long handle;
    int enabled;  /* Python clears it while the client needs its attention (dead, parked, ...) */
    uint8_t session_id;
    uint8_t key[4];                /* sessions with the key in the header (id < 0x80) */
    /* Sessions without a key are identified by the source address. Those with one are taken
     * here only from it too, the address Python admitted the session on: any other source (a
     * board's second socket, or a stranger outside --allow-from who knows the key) goes to
     * Python, which decides; this path never enforces or bypasses a policy. */
    struct sockaddr_storage addr;
    socklen_t addr_len;
    Stream *streams;
    Writer *writers;
    OutStream *out_streams;
    OutBestEffort *out_best_effort;
    uint16_t mtu;  /* the client's, for DATA sent here */
    /* Python sent a HEARTBEAT and times the ACKNACK that answers it (ClientProxy.rtt_s): every
     * ACKNACK is Python's until it clears this. */
    int probing;
    uint64_t messages, bytes, messages_out, bytes_out;
    int64_t last_seen_ns;  /* CLOCK_MONOTONIC, time.monotonic()'s clock; 0: nothing new */
    /* What the client's byte budget (MemoryBudget.over) leaves for reassembly here, as Python
     * last set it (set_room), less what was added since; and the bytes of reassembly added (or,
     * negative, given back) since the last fold, which Python charges to the client. */
    int64_t room, frag_charged;
    /* The receive time minus the client's transmit time of its last TIMESTAMP answered here
     * (ClientProxy.timestamp_skew_ns); has_skew: one came since the last fold. */
    int64_t timestamp_skew_ns;
    int has_skew;
} Client;

/* A datagram the receive thread leaves to Python (_receive_thread.c), in arrival order; or, with
 * a reader token, a sample of that reader's (its CDR with the encapsulation header). */
typedef struct Handed {
    struct Handed *next;
    long reader_token;  /* 0: a datagram */
    size_t length;
    struct sockaddr_storage from;
    socklen_t from_len;
    uint8_t data[];
} Handed;

typedef struct Receiver {
    PyObject_HEAD
    int sock;
    /* Registration runs on the loop's thread (and under the engine's lock on others), reading on
     * the receive thread: the mutex keeps either from seeing the tables half changed. */
    pthread_mutex_t mutex;
    Client *clients;
    long next_handle;
    int enabled;
    /* Agent-wide counters since the last fold. */
    uint64_t messages, bytes, samples, stale, publish_errors, acknacks, acknack_bytes;
    uint64_t timestamp_replies, timestamp_reply_bytes;  /* TIMESTAMP_REPLYs sent here */
    uint64_t fragments_in;
    size_t reassembly_limit;  /* Agent.max_reassembly_bytes; 0 (not set): no reassembly here */
    /* The streams whose ack_due went up since the last sweep (a stream past PENDING_ACKS is found
     * by fold's walk instead): a batch's end acknowledges these without walking every client. */
    struct { Client *client; Stream *stream; } pending[PENDING_ACKS];
    int pending_count;
    int pending_overflow;  /* a stream owed one past PENDING_ACKS: only fold's walk has it */
    /* BATCH * 64 KB mapped lazily: only the pages datagrams touch become resident. */
    uint8_t (*buffers)[MAX_DATAGRAM];
    struct mmsghdr messages_hdr[BATCH];
    struct iovec vectors[BATCH];
    struct sockaddr_storage sources[BATCH];
    /* The receive thread (_receive_thread.c); running: started and not yet stopped. Python
     * writes control_fd's counter to make the thread look at stopping and the hand-off again; the
     * thread writes notify_fd (Python's eventfd) once per hand-off not yet taken (notified). */
    pthread_t thread;
    int running, stopping, control_fd, notify_fd, notified;
    int paused;  /* Python's pause() calls not yet resumed: everything is Python's meanwhile */
    Handed *handoff_head, *handoff_tail;
    /* Readers (_reader_out.c): the callback of each writes samples_fd, which the thread polls. */
    Reader *readers;
    long next_reader_token;
    int samples_fd;
    uint8_t *take_buffer;   /* rcl's serialized message buffer, the rcutils allocator's */
    size_t take_capacity;
    /* DATA went out here on a reliable stream since Python last scheduled its HEARTBEAT round
     * (heartbeat_due): Python is woken once for it, not per message. */
    int heartbeat_due;
    uint64_t samples_out, reader_messages, reader_bytes;
    int readers_counted;        /* some reader's counters moved since the last fold_readers */
    uint64_t requests_expired;  /* repliers' requests the board never answered, since the last
                                 * take_expired */
    int handoff_count;
    size_t handoff_bytes;
    uint64_t handoff_dropped;
} Receiver;

static inline int64_t now_ns(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (int64_t)ts.tv_sec * 1000000000 + ts.tv_nsec;
}

/* 16-bit serial-number order (xrce/wire/streams.py seq_less). */
static inline int seq_less(uint16_t a, uint16_t b) {
    if (a == b) return 0;
    return (a < b && b - a < 0x8000) || (a > b && a - b > 0x8000);
}

/* A datagram of ``length`` bytes from ``c`` handled here, counted as Python counts one. */
static inline void count_message(Receiver *self, Client *c, size_t length) {
    c->messages++;
    c->bytes += length;
    c->last_seen_ns = now_ns();
    self->messages++;
    self->bytes += length;
}

static inline Writer *find_writer(Client *c, uint16_t object_id) {
    for (Writer *w = c->writers; w; w = w->next)
        if (w->object_id == object_id) return w;
    return NULL;
}

static inline Stream *find_stream(Client *c, uint8_t stream_id) {
    for (Stream *s = c->streams; s; s = s->next)
        if (s->stream_id == stream_id) return s;
    return NULL;
}

static inline Client *client_by_handle(Receiver *self, long handle) {
    for (Client *c = self->clients; c; c = c->next)
        if (c->handle == handle) return c;
    return NULL;
}

/* _fastpath.c */
void *loaded_symbol(const char *library_name, const char *symbol);
int try_fast(Receiver *self, uint8_t *data, size_t length, const struct sockaddr_storage *from);
int send_due_acknacks(Receiver *self);
int map_buffers(Receiver *self);
PyObject *address_tuple(const struct sockaddr_storage *addr);

/* _receive_thread.c */
void stop_receive_thread(Receiver *self);
PyObject *Receiver_start(Receiver *self, PyObject *arg);
PyObject *Receiver_stop(Receiver *self, PyObject *unused);
PyObject *Receiver_take(Receiver *self, PyObject *unused);
PyObject *Receiver_pause(Receiver *self, PyObject *unused);
PyObject *Receiver_resume(Receiver *self, PyObject *unused);
PyObject *Receiver_handoff_dropped(Receiver *self, PyObject *unused);

/* _receiver_tables.c */
void free_client(Client *client);
int parse_address(PyObject *tuple, struct sockaddr_storage *out, socklen_t *len);
PyObject *Receiver_add_client(Receiver *self, PyObject *args);
PyObject *Receiver_remove_client(Receiver *self, PyObject *args);
PyObject *Receiver_set_client_enabled(Receiver *self, PyObject *args);
PyObject *Receiver_set_enabled(Receiver *self, PyObject *args);
PyObject *Receiver_add_stream(Receiver *self, PyObject *args);
PyObject *Receiver_reliable_state(Receiver *self, PyObject *args);
PyObject *Receiver_set_reliable_state(Receiver *self, PyObject *args);
PyObject *Receiver_stream_accept(Receiver *self, PyObject *args);
PyObject *Receiver_stream_seq(Receiver *self, PyObject *args);
PyObject *Receiver_add_writer(Receiver *self, PyObject *args);
PyObject *Receiver_remove_writer(Receiver *self, PyObject *args);

/* _reader_out.c */
extern rcutils_allocator_t take_allocator;
int ensure_take_buffer(Receiver *self);
void on_new_message(const void *user_data, size_t count);
long link_reader(Receiver *self, Reader *r, long handle, int object_id,
                 unsigned long long address, set_event_callback_fn set_callback);
void deliver_samples(Receiver *self);
void detach_readers(Receiver *self, Client *c);
void free_readers(Receiver *self);
void free_take_buffer(Receiver *self);
int handoff_append(Receiver *self, long reader_token, const uint8_t *data, size_t length,
                   const struct sockaddr_storage *from, socklen_t from_len);
void wake_python(Receiver *self);
PyObject *resolve_rcl_readers(void);
PyObject *Receiver_add_reader(Receiver *self, PyObject *args);
PyObject *Receiver_remove_reader(Receiver *self, PyObject *args);
PyObject *Receiver_set_reader_direct(Receiver *self, PyObject *args);
PyObject *Receiver_set_reader_client(Receiver *self, PyObject *args);
PyObject *Receiver_reclaim_reader(Receiver *self, PyObject *arg);
PyObject *Receiver_heartbeat_due(Receiver *self, PyObject *arg);
PyObject *Receiver_fold_readers(Receiver *self, PyObject *unused);
PyObject *Receiver_add_out_best_effort(Receiver *self, PyObject *args);
PyObject *Receiver_out_best_effort_next(Receiver *self, PyObject *args);

/* _replier_out.c */
int resolve_rcl_services(void);
void deliver_requests(Receiver *self, Reader *r);
Reader *find_replier(Receiver *self, Client *c, uint16_t object_id);
int replier_reply(Receiver *self, Reader *r, uint8_t *sample, size_t length, int final);
void free_service_part(Reader *r);
int send_direct(Receiver *self, Reader *r, const uint8_t *lead, size_t lead_length,
                const uint8_t *cdr, size_t length);
PyObject *Receiver_add_replier(Receiver *self, PyObject *args);
PyObject *Receiver_send_reply(Receiver *self, PyObject *args);
PyObject *Receiver_replier_sequence(Receiver *self, PyObject *arg);
PyObject *Receiver_take_expired(Receiver *self, PyObject *unused);

/* _reliable_out.c */
OutStream *find_out_stream(Client *c, uint8_t stream_id);
void out_stream_release(OutStream *o, uint16_t acknowledged);
int try_fast_acknack(Receiver *self, Client *client, const uint8_t *data, size_t length);
void free_out_streams(Client *client);
PyObject *Receiver_add_out_stream(Receiver *self, PyObject *args);
PyObject *Receiver_out_acknowledged(Receiver *self, PyObject *args);
PyObject *Receiver_set_out_state(Receiver *self, PyObject *args);
PyObject *Receiver_set_probing(Receiver *self, PyObject *args);
PyObject *Receiver_out_reserve(Receiver *self, PyObject *args);
PyObject *Receiver_out_state(Receiver *self, PyObject *args);
PyObject *Receiver_out_message(Receiver *self, PyObject *args);
PyObject *Receiver_set_out_held(Receiver *self, PyObject *args);

/* _reliable_in.c */
int try_fast_fragment(Receiver *self, Client *client, Stream *stream, uint8_t *data,
                      size_t length, size_t pos, size_t sub_length);
int try_fast_heartbeat(Receiver *self, Client *client, const uint8_t *data, size_t length);
void free_reassembly(Stream *stream);
void stream_delivered(Receiver *self, Client *client, Stream *stream, uint16_t seq, size_t length);
int send_stream_acknack(Receiver *self, Client *client, Stream *stream, uint16_t bitmap);
PyObject *Receiver_take_partial(Receiver *self, PyObject *args);
PyObject *Receiver_put_partial(Receiver *self, PyObject *args);
PyObject *Receiver_set_room(Receiver *self, PyObject *args);
PyObject *Receiver_set_reassembly_limit(Receiver *self, PyObject *arg);
PyObject *Receiver_fold_reliable(Receiver *self, PyObject *unused);

#endif
