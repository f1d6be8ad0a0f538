/* A plain DDS board on eProsima's Micro XRCE-DDS Client: a HelloWorld {uint32 index; string message;}
 * writer of HelloWorldTopic and reader of HelloWorldDown, created by XML ("xml") or in binary
 * ("bin"), as eProsima's own HelloWorld examples make theirs. Built and run by tests/dds.
 *
 *   hello_dds xml|bin IP PORT DOMAIN SAMPLES
 *
 * Prints "status <0/1>" after the creations, "down <index> <message>" per sample read, and
 * "wrote <n>" at the end; writes SAMPLES samples ("eprosima says <i>") 100 ms apart, then keeps
 * reading for up to 3 s more until it has read 3. */
#include <uxr/client/client.h>
#include <ucdr/microcdr.h>

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define STREAM_HISTORY 8
#define BUFFER_SIZE (UXR_CONFIG_UDP_TRANSPORT_MTU * STREAM_HISTORY)

static int downs;

static void on_topic(uxrSession* session, uxrObjectId object_id, uint16_t request_id,
                     uxrStreamId stream_id, struct ucdrBuffer* ub, uint16_t length, void* args)
{
    (void)session; (void)object_id; (void)request_id; (void)stream_id; (void)length; (void)args;
    uint32_t index = 0;
    char message[128] = {0};
    ucdr_deserialize_uint32_t(ub, &index);
    ucdr_deserialize_string(ub, message, sizeof message);
    printf("down %u %s\n", index, message);
    fflush(stdout);
    downs++;
}

static const char* endpoint_xml(const char* kind, const char* topic)
{
    static char text[512];
    snprintf(text, sizeof text,
             "<dds><%s><topic><kind>NO_KEY</kind><name>%s</name><dataType>HelloWorld</dataType>"
             "<historyQos><kind>KEEP_LAST</kind><depth>8</depth></historyQos></topic>"
             "<qos><reliability><kind>RELIABLE</kind></reliability></qos></%s></dds>",
             kind, topic, kind);
    return text;
}

int main(int argc, char** argv)
{
    if (argc != 6) {
        fprintf(stderr, "usage: %s xml|bin IP PORT DOMAIN SAMPLES\n", argv[0]);
        return 2;
    }
    int xml = strcmp(argv[1], "xml") == 0;
    uint16_t domain = (uint16_t)atoi(argv[4]);
    int samples = atoi(argv[5]);

    uxrUDPTransport transport;
    if (!uxr_init_udp_transport(&transport, UXR_IPv4, argv[2], argv[3])) {
        printf("transport failed\n");
        return 1;
    }
    uxrSession session;
    uxr_init_session(&session, &transport.comm, 0x5A5A0050);
    uxr_set_topic_callback(&session, on_topic, NULL);
    if (!uxr_create_session(&session)) {
        printf("session failed\n");
        return 1;
    }
    static uint8_t output[BUFFER_SIZE], input[BUFFER_SIZE];
    uxrStreamId out = uxr_create_output_reliable_stream(&session, output, BUFFER_SIZE, STREAM_HISTORY);
    uxrStreamId in = uxr_create_input_reliable_stream(&session, input, BUFFER_SIZE, STREAM_HISTORY);

    uxrObjectId participant = uxr_object_id(0x01, UXR_PARTICIPANT_ID);
    uxrObjectId up_topic = uxr_object_id(0x01, UXR_TOPIC_ID);
    uxrObjectId down_topic = uxr_object_id(0x02, UXR_TOPIC_ID);
    uxrObjectId publisher = uxr_object_id(0x01, UXR_PUBLISHER_ID);
    uxrObjectId subscriber = uxr_object_id(0x01, UXR_SUBSCRIBER_ID);
    uxrObjectId writer = uxr_object_id(0x01, UXR_DATAWRITER_ID);
    uxrObjectId reader = uxr_object_id(0x01, UXR_DATAREADER_ID);
    uint16_t requests[7];
    if (xml) {
        requests[0] = uxr_buffer_create_participant_xml(&session, out, participant, domain,
            "<dds><participant><rtps><name>default_xrce_participant</name></rtps></participant></dds>",
            UXR_REPLACE);
        requests[1] = uxr_buffer_create_topic_xml(&session, out, up_topic, participant,
            "<dds><topic><name>HelloWorldTopic</name><dataType>HelloWorld</dataType></topic></dds>",
            UXR_REPLACE);
        requests[2] = uxr_buffer_create_topic_xml(&session, out, down_topic, participant,
            "<dds><topic><name>HelloWorldDown</name><dataType>HelloWorld</dataType></topic></dds>",
            UXR_REPLACE);
        requests[3] = uxr_buffer_create_publisher_xml(&session, out, publisher, participant, "", UXR_REPLACE);
        requests[4] = uxr_buffer_create_subscriber_xml(&session, out, subscriber, participant, "", UXR_REPLACE);
        requests[5] = uxr_buffer_create_datawriter_xml(&session, out, writer, publisher,
            endpoint_xml("data_writer", "HelloWorldTopic"), UXR_REPLACE);
        requests[6] = uxr_buffer_create_datareader_xml(&session, out, reader, subscriber,
            endpoint_xml("data_reader", "HelloWorldDown"), UXR_REPLACE);
    } else {
        uxrQoS_t qos = {UXR_DURABILITY_VOLATILE, UXR_RELIABILITY_RELIABLE, UXR_HISTORY_KEEP_LAST, 8};
        requests[0] = uxr_buffer_create_participant_bin(&session, out, participant, domain,
                                                        "hello_eprosima", UXR_REPLACE);
        requests[1] = uxr_buffer_create_topic_bin(&session, out, up_topic, participant,
                                                  "HelloWorldTopic", "HelloWorld", UXR_REPLACE);
        requests[2] = uxr_buffer_create_topic_bin(&session, out, down_topic, participant,
                                                  "HelloWorldDown", "HelloWorld", UXR_REPLACE);
        requests[3] = uxr_buffer_create_publisher_bin(&session, out, publisher, participant, UXR_REPLACE);
        requests[4] = uxr_buffer_create_subscriber_bin(&session, out, subscriber, participant, UXR_REPLACE);
        requests[5] = uxr_buffer_create_datawriter_bin(&session, out, writer, publisher, up_topic,
                                                       qos, UXR_REPLACE);
        requests[6] = uxr_buffer_create_datareader_bin(&session, out, reader, subscriber, down_topic,
                                                       qos, UXR_REPLACE);
    }
    uint8_t status[7];
    int created = uxr_run_session_until_all_status(&session, 30000, requests, status, 7);
    printf("status %d", created);
    for (int i = 0; i < 7; i++) {
        printf(" %u", status[i]);
    }
    printf("\n");
    fflush(stdout);
    if (!created) {
        return 1;
    }
    uxrDeliveryControl delivery = {0};
    delivery.max_samples = UXR_MAX_SAMPLES_UNLIMITED;
    uxr_buffer_request_data(&session, out, reader, in, &delivery);

    int wrote = 0;
    for (int i = 1; i <= samples; i++) {
        char message[64];
        snprintf(message, sizeof message, "eprosima says %d", i);
        ucdrBuffer ub;
        uint32_t size = 4 + 4 + (uint32_t)strlen(message) + 1;
        if (uxr_prepare_output_stream(&session, out, writer, &ub, size)) {
            ucdr_serialize_uint32_t(&ub, (uint32_t)i);
            ucdr_serialize_string(&ub, message);
            wrote++;
        }
        uxr_run_session_time(&session, 100);
    }
    for (int i = 0; i < 30 && downs < 3; i++) {
        uxr_run_session_time(&session, 100);
    }
    printf("wrote %d\n", wrote);
    fflush(stdout);
    uxr_delete_session(&session);
    uxr_close_udp_transport(&transport);
    return 0;
}
