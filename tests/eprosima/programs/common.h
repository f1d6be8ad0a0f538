/* What the suite's programs against eProsima's Micro XRCE-DDS Client share: a session over the
 * transport named on the command line (udp4 | udp6 | tcp4 | tcp6, host, port; or serial, the
 * descriptor of a pseudo-terminal the caller opened in place of the host, any port), with a reliable
 * output stream of HISTORY slots (8 by default, as eProsima's examples) and a reliable input one. */
#ifndef XRCE_TESTS_EPROSIMA_COMMON_H
#define XRCE_TESTS_EPROSIMA_COMMON_H

#include <uxr/client/client.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <termios.h>

#ifndef HISTORY
#define HISTORY 8
#endif
#define MTU 512
#define BUFFER_SIZE (MTU * HISTORY)

typedef struct {
    union {
        uxrUDPTransport udp;
        uxrTCPTransport tcp;
        uxrSerialTransport serial;
    } t;
    int tcp, serial;
    uxrSession session;
    uxrStreamId out;
    uxrStreamId in;
    uint8_t out_buffer[BUFFER_SIZE];
    uint8_t in_buffer[BUFFER_SIZE];
} Client;

/* argv: transport host port. 0 when the session is up; prints why not otherwise. */
static int open_client(Client *c, const char *kind, const char *host, const char *port, uint32_t key) {
    uxrIpProtocol family = (kind[3] == '6') ? UXR_IPv6 : UXR_IPv4;
    uxrCommunication *comm;
    c->tcp = kind[0] == 't';
    c->serial = kind[0] == 's';
    if (c->serial) {
        int fd = atoi(host);
        struct termios tio;
        if (tcgetattr(fd, &tio) == 0) {
            cfmakeraw(&tio);
            tcsetattr(fd, TCSANOW, &tio);
        }
        if (!uxr_init_serial_transport(&c->t.serial, fd, 0, 1)) {  /* agent 0, client 1 */
            printf("ERROR transport\n");
            return 1;
        }
        comm = &c->t.serial.comm;
    } else if (c->tcp) {
        if (!uxr_init_tcp_transport(&c->t.tcp, family, host, port)) {
            printf("ERROR transport\n");
            return 1;
        }
        comm = &c->t.tcp.comm;
    } else {
        if (!uxr_init_udp_transport(&c->t.udp, family, host, port)) {
            printf("ERROR transport\n");
            return 1;
        }
        comm = &c->t.udp.comm;
    }
    uxr_init_session(&c->session, comm, key);
    if (!uxr_create_session(&c->session)) {
        printf("ERROR session\n");
        return 1;
    }
    c->out = uxr_create_output_reliable_stream(&c->session, c->out_buffer, BUFFER_SIZE, HISTORY);
    c->in = uxr_create_input_reliable_stream(&c->session, c->in_buffer, BUFFER_SIZE, HISTORY);
    return 0;
}

static void close_client(Client *c) {
    uxr_delete_session(&c->session);
    if (c->serial) uxr_close_serial_transport(&c->t.serial);
    else if (c->tcp) uxr_close_tcp_transport(&c->t.tcp);
    else uxr_close_udp_transport(&c->t.udp);
}

#endif
