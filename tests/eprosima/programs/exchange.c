/* Two clients of eProsima's Micro XRCE-DDS Client in one process, a writer and a reader of one
 * topic with a type name that is no ROS one ("Exchange": uint32 index, sequence<octet> body),
 * exchanging samples through the agent over a custom transport of this program's that drops a
 * given share of the datagrams both ways, deterministically (a seeded xorshift per client and
 * direction), as a lossy radio link would.
 *
 *   exchange udp4|udp6|tcp4|tcp6 HOST PORT  STREAM COUNT SIZE DROP SEED FORMAT SETTLE
 *   exchange serial FD_WRITER FD_READER     STREAM COUNT SIZE DROP SEED FORMAT SETTLE
 *
 * STREAM reliable | best-effort (the writer's output stream, the reader's input stream and both
 * endpoints' QoS); COUNT samples of SIZE body bytes (past the MTU of 512 on a reliable stream the
 * library fragments them); DROP percent of messages dropped (serial: of frames); FORMAT xml | ref |
 * bin (the entities' representation); SETTLE milliseconds both sessions run between creating and
 * writing (DDS matching, -m dds). Serial: the descriptors are the client ends of two pseudo-terminal
 * pairs the caller opened, framed as eProsima's serial transport frames (client address 1, agent 0).
 *
 * Prints "STATUS reader|writer <code>..." after each client's creations, "GOT <index> <length>
 * ok|bad" per sample read, "WROTE <n>", then "DROPPED <writer out> <writer in> <reader out>
 * <reader in>". Reliable: runs until every sample is read (20 s at most); best-effort: until 1 s
 * after the last write. Exit 0 when the creations succeeded and (reliable) every sample arrived
 * intact, once each, in order; 1 otherwise. */
#include <uxr/client/client.h>
#include <ucdr/microcdr.h>

#include <errno.h>
#include <netdb.h>
#include <poll.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

#define MTU UXR_CONFIG_CUSTOM_TRANSPORT_MTU
#define HISTORY 8
#define MAX_BODY 4096

enum { UDP, TCP, SERIAL };

typedef struct {
    int kind;
    int fd;
    const char *host, *port;
    int family;
    uint32_t rng_out, rng_in;
    int drop;
    unsigned dropped_out, dropped_in;
    int dropping_in;             /* serial: inside a received frame that is dropped */
    int dropping_out;            /* serial: inside a written frame that is dropped */
    uint8_t rx[2 + MTU];         /* tcp: one length-prefixed message being read */
    size_t rx_len;
} Link;

typedef struct {
    Link link;
    uxrCustomTransport transport;
    uxrSession session;
    uxrStreamId reliable_out, best_effort_out, reliable_in, best_effort_in;
    uint8_t reliable_out_buffer[MTU * HISTORY], best_effort_out_buffer[MTU], reliable_in_buffer[MTU * HISTORY];
} Client;

static uint32_t xorshift(uint32_t *state) {
    uint32_t x = *state;
    x ^= x << 13;
    x ^= x >> 17;
    x ^= x << 5;
    return *state = x;
}

static int drops(Link *link, uint32_t *state) {
    return link->drop > 0 && (int)(xorshift(state) % 100) < link->drop;
}

static int64_t now_ms(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (int64_t)ts.tv_sec * 1000 + ts.tv_nsec / 1000000;
}

static bool link_open(uxrCustomTransport *t) {
    Link *link = t->args;
    if (link->kind == SERIAL) {
        struct termios tio;
        if (tcgetattr(link->fd, &tio) == 0) {
            cfmakeraw(&tio);
            tcsetattr(link->fd, TCSANOW, &tio);
        }
        return true;
    }
    struct addrinfo hints = {0}, *found;
    hints.ai_family = link->family;
    hints.ai_socktype = link->kind == TCP ? SOCK_STREAM : SOCK_DGRAM;
    if (getaddrinfo(link->host, link->port, &hints, &found) != 0) return false;
    link->fd = socket(found->ai_family, found->ai_socktype, 0);
    int ok = link->fd >= 0 && connect(link->fd, found->ai_addr, found->ai_addrlen) == 0;
    freeaddrinfo(found);
    return ok;
}

static bool link_close(uxrCustomTransport *t) {
    Link *link = t->args;
    if (link->kind != SERIAL) close(link->fd);
    return true;
}

static int write_all(int fd, const uint8_t *data, size_t length) {
    while (length > 0) {
        ssize_t n = write(fd, data, length);
        if (n < 0 && errno == EINTR) continue;
        if (n <= 0) return 0;
        data += n;
        length -= (size_t)n;
    }
    return 1;
}

static size_t link_write(uxrCustomTransport *t, const uint8_t *buffer, size_t length, uint8_t *error) {
    Link *link = t->args;
    if (link->kind == SERIAL) {
        /* The framing writes a frame in chunks, the first opening with the flag 7E (escaped
         * everywhere else): the decision is taken there and holds for the frame's other chunks. */
        if (length > 0 && buffer[0] == UXR_FRAMING_BEGIN_FLAG) {
            link->dropping_out = drops(link, &link->rng_out);
            if (link->dropping_out) link->dropped_out++;
        }
        if (link->dropping_out) return length;
        if (!write_all(link->fd, buffer, length)) {
            *error = 1;
            return 0;
        }
        return length;
    }
    if (drops(link, &link->rng_out)) {
        link->dropped_out++;
        return length;
    }
    if (link->kind == UDP) {
        ssize_t n = send(link->fd, buffer, length, 0);
        if (n < 0) {
            *error = 1;
            return 0;
        }
        return (size_t)n;
    }
    uint8_t prefix[2] = {(uint8_t)(length & 0xff), (uint8_t)(length >> 8)};  /* eProsima's TCP framing */
    if (!write_all(link->fd, prefix, 2) || !write_all(link->fd, buffer, length)) {
        *error = 1;
        return 0;
    }
    return length;
}

static int wait_readable(int fd, int timeout) {
    struct pollfd p = {fd, POLLIN, 0};
    return poll(&p, 1, timeout < 0 ? 0 : timeout) > 0;
}

static size_t link_read(uxrCustomTransport *t, uint8_t *buffer, size_t length, int timeout, uint8_t *error) {
    Link *link = t->args;
    if (!wait_readable(link->fd, timeout)) return 0;
    if (link->kind == UDP) {
        ssize_t n = recv(link->fd, buffer, length, 0);
        if (n <= 0) {
            *error = 1;
            return 0;
        }
        if (drops(link, &link->rng_in)) {
            link->dropped_in++;
            return 0;
        }
        return (size_t)n;
    }
    if (link->kind == SERIAL) {
        uint8_t raw[256];
        ssize_t n = read(link->fd, raw, length < sizeof raw ? length : sizeof raw);
        if (n <= 0) return 0;
        size_t kept = 0;
        for (ssize_t i = 0; i < n; i++) {
            if (raw[i] == UXR_FRAMING_BEGIN_FLAG) {
                link->dropping_in = drops(link, &link->rng_in);
                if (link->dropping_in) link->dropped_in++;
            }
            if (!link->dropping_in) buffer[kept++] = raw[i];
        }
        return kept;
    }
    /* TCP: a two-byte little-endian length, then the message; a partial one waits for the rest. */
    for (;;) {
        size_t want = link->rx_len < 2 ? 2 : 2 + (size_t)(link->rx[0] | (link->rx[1] << 8));
        if (want > sizeof link->rx) {
            *error = 1;
            return 0;
        }
        if (link->rx_len == want && want > 2) break;
        ssize_t n = read(link->fd, link->rx + link->rx_len, want - link->rx_len);
        if (n <= 0) {
            *error = 1;
            return 0;
        }
        link->rx_len += (size_t)n;
        if (link->rx_len < want && !wait_readable(link->fd, timeout)) return 0;
    }
    size_t size = link->rx_len - 2;
    link->rx_len = 0;
    if (drops(link, &link->rng_in)) {
        link->dropped_in++;
        return 0;
    }
    if (size > length) size = length;
    memcpy(buffer, link->rx + 2, size);
    return size;
}

static int reliable_stream, count, body_size, got, bad, last_index;
static uxrObjectId reader_id;

static void on_topic(uxrSession *session, uxrObjectId object_id, uint16_t request_id, uxrStreamId stream_id,
                     struct ucdrBuffer *ub, uint16_t length, void *args) {
    (void)session; (void)request_id; (void)stream_id; (void)length; (void)args;
    if (object_id.id != reader_id.id || object_id.type != reader_id.type) return;
    static uint8_t body[MAX_BODY];
    uint32_t index = 0, size = 0;
    ucdr_deserialize_uint32_t(ub, &index);
    int ok = ucdr_deserialize_sequence_uint8_t(ub, body, sizeof body, &size);
    for (uint32_t i = 0; ok && i < size; i++) ok = body[i] == (uint8_t)(index * 7 + i);
    ok = ok && (int)size == body_size && (int)index > last_index;
    printf("GOT %u %u %s\n", index, size, ok ? "ok" : "bad");
    fflush(stdout);
    if ((int)index > last_index) last_index = (int)index;
    got++;
    bad += !ok;
}

static const char *qos_xml(const char *kind, const char *topic_name) {
    static char text[512];
    snprintf(text, sizeof text,
             "<dds><%s><topic><kind>NO_KEY</kind><name>%s</name><dataType>Exchange</dataType></topic>"
             "<qos><reliability><kind>%s</kind></reliability></qos></%s></dds>",
             kind, topic_name, reliable_stream ? "RELIABLE" : "BEST_EFFORT", kind);
    return text;
}

/* Participant, topic, publisher or subscriber, writer or reader, in FORMAT; prints their STATUS. */
static int create(Client *c, int writer, const char *format) {
    uxrSession *s = &c->session;
    uxrStreamId out = c->reliable_out;
    uxrObjectId participant = uxr_object_id(1, UXR_PARTICIPANT_ID), topic = uxr_object_id(1, UXR_TOPIC_ID);
    uxrObjectId group = uxr_object_id(1, writer ? UXR_PUBLISHER_ID : UXR_SUBSCRIBER_ID);
    uxrObjectId endpoint = uxr_object_id(1, writer ? UXR_DATAWRITER_ID : UXR_DATAREADER_ID);
    uint16_t requests[4];
    uxrQoS_t qos = {UXR_DURABILITY_VOLATILE,
                    reliable_stream ? UXR_RELIABILITY_RELIABLE : UXR_RELIABILITY_BEST_EFFORT,
                    UXR_HISTORY_KEEP_LAST, 10};
    const char *domain = getenv("ROS_DOMAIN_ID");
    uint16_t domain_id = domain ? (uint16_t)atoi(domain) : 0;
    if (strcmp(format, "bin") == 0) {
        requests[0] = uxr_buffer_create_participant_bin(s, out, participant, domain_id, "exchange", UXR_REPLACE);
        requests[1] = uxr_buffer_create_topic_bin(s, out, topic, participant, "ExchangeTopic", "Exchange", UXR_REPLACE);
        requests[2] = writer ? uxr_buffer_create_publisher_bin(s, out, group, participant, UXR_REPLACE)
                             : uxr_buffer_create_subscriber_bin(s, out, group, participant, UXR_REPLACE);
        requests[3] = writer ? uxr_buffer_create_datawriter_bin(s, out, endpoint, group, topic, qos, UXR_REPLACE)
                             : uxr_buffer_create_datareader_bin(s, out, endpoint, group, topic, qos, UXR_REPLACE);
    } else if (strcmp(format, "xml") == 0) {
        requests[0] = uxr_buffer_create_participant_xml(s, out, participant, domain_id,
            "<dds><participant><rtps><name>exchange</name></rtps></participant></dds>", UXR_REPLACE);
        requests[1] = uxr_buffer_create_topic_xml(s, out, topic, participant,
            "<dds><topic><name>ExchangeTopic</name><dataType>Exchange</dataType></topic></dds>", UXR_REPLACE);
        requests[2] = writer ? uxr_buffer_create_publisher_xml(s, out, group, participant, "", UXR_REPLACE)
                             : uxr_buffer_create_subscriber_xml(s, out, group, participant, "", UXR_REPLACE);
        requests[3] = writer
            ? uxr_buffer_create_datawriter_xml(s, out, endpoint, group, qos_xml("data_writer", "ExchangeTopic"), UXR_REPLACE)
            : uxr_buffer_create_datareader_xml(s, out, endpoint, group, qos_xml("data_reader", "ExchangeTopic"), UXR_REPLACE);
    } else {
        /* References as CED reads them: a topic's is its name with "__t", an endpoint's names its
         * topic with "__dw" / "__dr". */
        requests[0] = uxr_buffer_create_participant_ref(s, out, participant, domain_id, "participant", UXR_REPLACE);
        requests[1] = uxr_buffer_create_topic_ref(s, out, topic, participant, "ExchangeTopic__t", UXR_REPLACE);
        requests[2] = writer ? uxr_buffer_create_publisher_xml(s, out, group, participant, "", UXR_REPLACE)
                             : uxr_buffer_create_subscriber_xml(s, out, group, participant, "", UXR_REPLACE);
        requests[3] = writer ? uxr_buffer_create_datawriter_ref(s, out, endpoint, group, "ExchangeTopic__dw", UXR_REPLACE)
                             : uxr_buffer_create_datareader_ref(s, out, endpoint, group, "ExchangeTopic__dr", UXR_REPLACE);
    }
    uint8_t status[4] = {0};
    int ok = uxr_run_session_until_all_status(s, 30000, requests, status, 4);
    printf("STATUS %s %u %u %u %u\n", writer ? "writer" : "reader", status[0], status[1], status[2], status[3]);
    fflush(stdout);
    return ok;
}

static int open_client(Client *c, int kind, const char *host, const char *port, int family, int fd,
                       int drop, uint32_t seed, uint32_t key) {
    c->link = (Link){.kind = kind, .fd = fd, .host = host, .port = port, .family = family, .drop = drop,
                     .rng_out = seed * 2654435761u + key, .rng_in = seed * 2246822519u + key};
    if (c->link.rng_out == 0) c->link.rng_out = 1;
    if (c->link.rng_in == 0) c->link.rng_in = 1;
    uxr_set_custom_transport_callbacks(&c->transport, kind == SERIAL, link_open, link_close, link_write, link_read);
    if (!uxr_init_custom_transport(&c->transport, &c->link)) {
        printf("ERROR transport\n");
        return 0;
    }
    uxr_init_session(&c->session, &c->transport.comm, key);
    uxr_set_topic_callback(&c->session, on_topic, NULL);
    if (!uxr_create_session(&c->session)) {
        printf("ERROR session %08x\n", key);
        return 0;
    }
    c->reliable_out = uxr_create_output_reliable_stream(&c->session, c->reliable_out_buffer,
                                                        sizeof c->reliable_out_buffer, HISTORY);
    c->best_effort_out = uxr_create_output_best_effort_stream(&c->session, c->best_effort_out_buffer,
                                                              sizeof c->best_effort_out_buffer);
    c->reliable_in = uxr_create_input_reliable_stream(&c->session, c->reliable_in_buffer,
                                                      sizeof c->reliable_in_buffer, HISTORY);
    c->best_effort_in = uxr_create_input_best_effort_stream(&c->session);
    return 1;
}

static Client writer, reader;

/* Both sessions, in turn, for ms milliseconds. */
static void pump(int ms) {
    int64_t end = now_ms() + ms;
    do {
        uxr_run_session_timeout(&writer.session, 1);
        uxr_run_session_timeout(&reader.session, 1);
    } while (now_ms() < end);
}

/* eProsima's client sends a HEARTBEAT for its unacknowledged reliable messages only once a session
 * has been polled for 100 ms (UXR_CONFIG_MIN_HEARTBEAT_TIME_INTERVAL) without hearing anything:
 * every poll moves the deadline on. pump()'s 1 ms turns would never let it, and a lost last
 * message would never be repeated; a session with something unacknowledged gets turns past that. */
static void settle(Client *c, Client *other, int ms) {
    int64_t end = now_ms() + ms;
    while (!uxr_run_session_timeout(&c->session, 150) && now_ms() < end)
        uxr_run_session_timeout(&other->session, 5);
}

int main(int argc, char **argv) {
    setvbuf(stdout, NULL, _IOLBF, 0);
    if (argc != 11) {
        fprintf(stderr, "usage: %s udp4|udp6|tcp4|tcp6 HOST PORT | serial FD_W FD_R, then "
                        "reliable|best-effort COUNT SIZE DROP SEED xml|ref|bin SETTLE_MS\n", argv[0]);
        return 2;
    }
    const char *kind_name = argv[1];
    int kind = kind_name[0] == 's' ? SERIAL : kind_name[0] == 't' ? TCP : UDP;
    int family = kind_name[3] == '6' ? AF_INET6 : AF_INET;
    reliable_stream = strcmp(argv[4], "reliable") == 0;
    count = atoi(argv[5]);
    body_size = atoi(argv[6]);
    int drop = atoi(argv[7]);
    uint32_t seed = (uint32_t)strtoul(argv[8], NULL, 0);
    const char *format = argv[9];
    int settle_ms = atoi(argv[10]);
    if (body_size > MAX_BODY) body_size = MAX_BODY;

    int w_fd = kind == SERIAL ? atoi(argv[2]) : -1, r_fd = kind == SERIAL ? atoi(argv[3]) : -1;
    if (!open_client(&reader, kind, argv[2], argv[3], family, r_fd, drop, seed, 0xE9052B02u)) return 1;
    if (!open_client(&writer, kind, argv[2], argv[3], family, w_fd, drop, seed, 0xE9052B01u)) return 1;

    reader_id = uxr_object_id(1, UXR_DATAREADER_ID);
    int created = create(&reader, 0, format);
    uxrDeliveryControl forever = {0};
    forever.max_samples = UXR_MAX_SAMPLES_UNLIMITED;
    uxr_buffer_request_data(&reader.session, reader.reliable_out, reader_id,
                            reliable_stream ? reader.reliable_in : reader.best_effort_in, &forever);
    settle(&reader, &writer, 10000);
    created = create(&writer, 1, format) && created;
    pump(settle_ms > 0 ? settle_ms : 50);

    uxrObjectId writer_id = uxr_object_id(1, UXR_DATAWRITER_ID);
    uxrStreamId out = reliable_stream ? writer.reliable_out : writer.best_effort_out;
    static uint8_t body[MAX_BODY];
    int wrote = 0;
    for (int index = 1; created && index <= count; index++) {
        for (int i = 0; i < body_size; i++) body[i] = (uint8_t)(index * 7 + i);
        uint32_t size = 4 + 4 + (uint32_t)body_size;
        int64_t give_up = now_ms() + 10000;
        ucdrBuffer ub;
        /* A reliable history of 8 may be full until the agent acknowledges: pump and try again. */
        int prepared;
        while (!(prepared = uxr_prepare_output_stream(&writer.session, out, writer_id, &ub, size) != 0)) {
            if (!reliable_stream || now_ms() > give_up) break;
            pump(5);
        }
        if (!prepared) continue;
        ucdr_serialize_uint32_t(&ub, (uint32_t)index);
        ucdr_serialize_sequence_uint8_t(&ub, body, (uint32_t)body_size);
        wrote++;
        uxr_flash_output_streams(&writer.session);
        pump(5);
    }
    printf("WROTE %d\n", wrote);
    if (reliable_stream) settle(&writer, &reader, 10000);
    int64_t end = now_ms() + (reliable_stream ? 10000 : 1000);
    while (now_ms() < end && !(reliable_stream && got >= count)) {
        uxr_run_session_timeout(&reader.session, 50);
        uxr_run_session_timeout(&writer.session, 1);
    }
    pump(100);  /* the last acknowledgments */
    printf("DROPPED %u %u %u %u\n", writer.link.dropped_out, writer.link.dropped_in,
           reader.link.dropped_out, reader.link.dropped_in);
    uxr_delete_session_retries(&writer.session, 3);
    uxr_delete_session_retries(&reader.session, 3);
    uxr_close_custom_transport(&writer.transport);
    uxr_close_custom_transport(&reader.transport);
    int ok = created && wrote == count && bad == 0 && (!reliable_stream || got == count);
    return ok ? 0 : 1;
}
