/* A board that creates its session and entities once and never again, as rmw_microxrcedds does
 * (binary creation, session 0x81, reliable stream 0x80 both ways, best-effort 0x01 out), built
 * against eProsima's Micro XRCE-DDS Client by tests/helpers/eprosima_client.py.
 *
 *   board_once udp HOST PORT SECONDS  |  board_once serial DEVICE SECONDS  |  serial-fd FD SECONDS
 *
 * Entities: participant "restart_board" (domain from ROS_DOMAIN_ID), a best-effort writer on
 * rt/board_sensor and a reliable one on rt/board_reliable (std_msgs/Int32, 10 Hz each, the count
 * as value), a reliable reader of rt/board_cmd (std_msgs/Int32) with a standing READ_DATA, and a
 * replier of /board_add (example_interfaces/AddTwoInts) with its own.
 * Prints READY once created, then CMD <value> per sample read and REPLY <a> <b> per request
 * answered, line-buffered: the test reads them. It never pings the agent, never re-creates. */
#include <uxr/client/client.h>
#include <ucdr/microcdr.h>

#include <fcntl.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

#define HISTORY 8
#define MTU 512

static uxrStreamId reliable_out, best_effort_out, reliable_in;
static uxrObjectId replier_id, reader_id;

static void on_topic(uxrSession* session, uxrObjectId object_id, uint16_t request_id,
                     uxrStreamId stream_id, struct ucdrBuffer* ub, uint16_t length, void* args)
{
    (void)session; (void)request_id; (void)stream_id; (void)length; (void)args;
    if (object_id.id == reader_id.id && object_id.type == reader_id.type) {
        int32_t value = 0;
        ucdr_deserialize_int32_t(ub, &value);
        printf("CMD %d\n", value);
    }
}

static void on_request(uxrSession* session, uxrObjectId object_id, uint16_t request_id,
                       SampleIdentity* sample_id, ucdrBuffer* ub, uint16_t length, void* args)
{
    (void)object_id; (void)request_id; (void)length; (void)args;
    int64_t a = 0, b = 0;
    ucdr_deserialize_int64_t(ub, &a);
    ucdr_deserialize_int64_t(ub, &b);
    uint8_t reply[8];
    ucdrBuffer out;
    ucdr_init_buffer(&out, reply, sizeof(reply));
    ucdr_serialize_int64_t(&out, a + b);
    uxr_buffer_reply(session, reliable_out, replier_id, sample_id, reply, sizeof(reply));
    printf("REPLY %lld %lld\n", (long long)a, (long long)b);
}

static double now_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return ts.tv_sec + ts.tv_nsec / 1e9;
}

int main(int argc, char** argv)
{
    setvbuf(stdout, NULL, _IOLBF, 0);
    if (argc < 4) {
        fprintf(stderr, "usage: board_once udp HOST PORT SECONDS | serial DEVICE SECONDS\n");
        return 2;
    }
    uxrUDPTransport udp;
    uxrSerialTransport serial;
    uxrCommunication* comm;
    double seconds;
    if (strcmp(argv[1], "udp") == 0 && argc >= 5) {
        if (!uxr_init_udp_transport(&udp, UXR_IPv4, argv[2], argv[3])) {
            fprintf(stderr, "no udp transport\n");
            return 1;
        }
        comm = &udp.comm;
        seconds = atof(argv[4]);
    } else {
        /* "serial-fd N": a descriptor the test hands over (the master of its pty pair). */
        int fd = strcmp(argv[1], "serial-fd") == 0 ? atoi(argv[2]) : open(argv[2], O_RDWR | O_NOCTTY);
        if (fd < 0) {
            perror("open");
            return 1;
        }
        struct termios tio;
        if (tcgetattr(fd, &tio) == 0) {
            cfmakeraw(&tio);
            tcsetattr(fd, TCSANOW, &tio);
        }
        if (!uxr_init_serial_transport(&serial, fd, 0, 1)) {
            fprintf(stderr, "no serial transport\n");
            return 1;
        }
        comm = &serial.comm;
        seconds = atof(argv[3]);
    }
    const char* domain_env = getenv("ROS_DOMAIN_ID");
    uint16_t domain = domain_env ? (uint16_t)atoi(domain_env) : 0;

    uxrSession session;
    uxr_init_session(&session, comm, 0x5107E51A);
    uxr_set_topic_callback(&session, on_topic, NULL);
    uxr_set_request_callback(&session, on_request, NULL);
    if (!uxr_create_session(&session)) {
        fprintf(stderr, "no session\n");
        return 1;
    }
    static uint8_t out_rel[MTU * HISTORY], out_be[MTU], in_rel[MTU * HISTORY];
    reliable_out = uxr_create_output_reliable_stream(&session, out_rel, sizeof(out_rel), HISTORY);
    best_effort_out = uxr_create_output_best_effort_stream(&session, out_be, sizeof(out_be));
    reliable_in = uxr_create_input_reliable_stream(&session, in_rel, sizeof(in_rel), HISTORY);
    uxr_create_input_best_effort_stream(&session);

    uint8_t mode = UXR_REUSE | UXR_REPLACE;  /* rmw_microxrcedds' flags */
    uxrObjectId participant = uxr_object_id(0x01, UXR_PARTICIPANT_ID);
    uxrObjectId topic_be = uxr_object_id(0x01, UXR_TOPIC_ID);
    uxrObjectId topic_rel = uxr_object_id(0x02, UXR_TOPIC_ID);
    uxrObjectId topic_cmd = uxr_object_id(0x03, UXR_TOPIC_ID);
    uxrObjectId publisher = uxr_object_id(0x01, UXR_PUBLISHER_ID);
    uxrObjectId subscriber = uxr_object_id(0x01, UXR_SUBSCRIBER_ID);
    uxrObjectId writer_be = uxr_object_id(0x01, UXR_DATAWRITER_ID);
    uxrObjectId writer_rel = uxr_object_id(0x02, UXR_DATAWRITER_ID);
    reader_id = uxr_object_id(0x01, UXR_DATAREADER_ID);
    replier_id = uxr_object_id(0x01, UXR_REPLIER_ID);
    uxrQoS_t best_effort = {.reliability = UXR_RELIABILITY_BEST_EFFORT,
                            .durability = UXR_DURABILITY_VOLATILE,
                            .history = UXR_HISTORY_KEEP_LAST, .depth = 5};
    uxrQoS_t reliable = {.reliability = UXR_RELIABILITY_RELIABLE,
                         .durability = UXR_DURABILITY_VOLATILE,
                         .history = UXR_HISTORY_KEEP_LAST, .depth = 10};
    const char* int32 = "std_msgs::msg::dds_::Int32_";
    uint16_t requests[11];
    int n = 0;
    requests[n++] = uxr_buffer_create_participant_bin(&session, reliable_out, participant, domain,
                                                      "restart_board", mode);
    requests[n++] = uxr_buffer_create_topic_bin(&session, reliable_out, topic_be, participant,
                                                "rt/board_sensor", int32, mode);
    requests[n++] = uxr_buffer_create_topic_bin(&session, reliable_out, topic_rel, participant,
                                                "rt/board_reliable", int32, mode);
    requests[n++] = uxr_buffer_create_topic_bin(&session, reliable_out, topic_cmd, participant,
                                                "rt/board_cmd", int32, mode);
    requests[n++] = uxr_buffer_create_publisher_bin(&session, reliable_out, publisher, participant,
                                                    mode);
    requests[n++] = uxr_buffer_create_datawriter_bin(&session, reliable_out, writer_be, publisher,
                                                     topic_be, best_effort, mode);
    requests[n++] = uxr_buffer_create_datawriter_bin(&session, reliable_out, writer_rel, publisher,
                                                     topic_rel, reliable, mode);
    requests[n++] = uxr_buffer_create_subscriber_bin(&session, reliable_out, subscriber,
                                                     participant, mode);
    requests[n++] = uxr_buffer_create_datareader_bin(&session, reliable_out, reader_id, subscriber,
                                                     topic_cmd, reliable, mode);
    requests[n++] = uxr_buffer_create_replier_bin(
        &session, reliable_out, replier_id, participant, "/board_add",
        "example_interfaces::srv::dds_::AddTwoInts_Request_",
        "example_interfaces::srv::dds_::AddTwoInts_Response_", "rq/board_addRequest",
        "rr/board_addReply", reliable, mode);
    uint8_t status[11];
    if (!uxr_run_session_until_all_status(&session, 10000, requests, status, (size_t)n)) {
        fprintf(stderr, "creation failed:");
        for (int i = 0; i < n; i++) fprintf(stderr, " %d", status[i]);
        fprintf(stderr, "\n");
        return 1;
    }
    uxrDeliveryControl forever = {0};
    forever.max_samples = UXR_MAX_SAMPLES_UNLIMITED;
    uxr_buffer_request_data(&session, reliable_out, reader_id, reliable_in, &forever);
    uxr_buffer_request_data(&session, reliable_out, replier_id, reliable_in, &forever);
    uxr_run_session_time(&session, 100);
    printf("READY\n");

    double end = now_s() + seconds, next = now_s();
    int32_t count = 0;
    while (now_s() < end) {
        if (now_s() >= next) {
            next += 0.1;
            ucdrBuffer ub;
            if (uxr_prepare_output_stream(&session, best_effort_out, writer_be, &ub, 4)) {
                ucdr_serialize_int32_t(&ub, count);
            }
            if (uxr_prepare_output_stream(&session, reliable_out, writer_rel, &ub, 4)) {
                ucdr_serialize_int32_t(&ub, count);
            }
            count++;
        }
        uxr_run_session_time(&session, 10);
    }
    printf("DONE %d\n", count);
    return 0;
}
