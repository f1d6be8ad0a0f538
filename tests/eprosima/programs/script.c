/* Creates entities as a script on stdin says, one line each, through eProsima's client:
 *
 *   KIND FORMAT ID PARENT MODE TEXT...
 *
 * KIND participant | topic | publisher | subscriber | datawriter | datareader; FORMAT xml | ref;
 * ID the object id's number; PARENT the parent's number (a participant's: its domain); MODE one
 * of create, reuse, replace, reuse+replace; TEXT the rest of the line (may be empty for groups).
 * Each CREATE is buffered and its STATUS awaited before the next line (as rmw_microxrcedds
 * does): the client then sends its next CREATE the moment the STATUS comes, whether or not the
 * agent's ACKNACK came with it. A line "batch N" buffers the next N lines back to back and
 * awaits all their STATUS at once.
 *
 * Prints "STATUS <line> <code>" per CREATE, or "FULL <line>" when the reliable output stream of
 * HISTORY slots had no room for it (no ACKNACK freed one), then exits 3. argv: transport host port. */
#include "common.h"

#define MAX_LINE 2048
#define MAX_BATCH 64

static uint8_t mode_of(const char *word) {
    uint8_t mode = 0;
    if (strstr(word, "reuse")) mode |= UXR_REUSE;
    if (strstr(word, "replace")) mode |= UXR_REPLACE;
    return mode;
}

static uint16_t buffer_create(Client *c, const char *kind, const char *format, int id, int parent,
                              uint8_t mode, const char *text) {
    uxrSession *s = &c->session;
    int xml = strcmp(format, "xml") == 0;
    if (strcmp(kind, "participant") == 0) {
        uxrObjectId o = uxr_object_id(id, UXR_PARTICIPANT_ID);
        return xml ? uxr_buffer_create_participant_xml(s, c->out, o, parent, text, mode)
                   : uxr_buffer_create_participant_ref(s, c->out, o, parent, text, mode);
    }
    if (strcmp(kind, "topic") == 0) {
        uxrObjectId o = uxr_object_id(id, UXR_TOPIC_ID), p = uxr_object_id(parent, UXR_PARTICIPANT_ID);
        return xml ? uxr_buffer_create_topic_xml(s, c->out, o, p, text, mode)
                   : uxr_buffer_create_topic_ref(s, c->out, o, p, text, mode);
    }
    if (strcmp(kind, "publisher") == 0)
        return uxr_buffer_create_publisher_xml(s, c->out, uxr_object_id(id, UXR_PUBLISHER_ID),
                                               uxr_object_id(parent, UXR_PARTICIPANT_ID), text, mode);
    if (strcmp(kind, "subscriber") == 0)
        return uxr_buffer_create_subscriber_xml(s, c->out, uxr_object_id(id, UXR_SUBSCRIBER_ID),
                                                uxr_object_id(parent, UXR_PARTICIPANT_ID), text, mode);
    if (strcmp(kind, "datawriter") == 0) {
        uxrObjectId o = uxr_object_id(id, UXR_DATAWRITER_ID), p = uxr_object_id(parent, UXR_PUBLISHER_ID);
        return xml ? uxr_buffer_create_datawriter_xml(s, c->out, o, p, text, mode)
                   : uxr_buffer_create_datawriter_ref(s, c->out, o, p, text, mode);
    }
    if (strcmp(kind, "datareader") == 0) {
        uxrObjectId o = uxr_object_id(id, UXR_DATAREADER_ID), p = uxr_object_id(parent, UXR_SUBSCRIBER_ID);
        return xml ? uxr_buffer_create_datareader_xml(s, c->out, o, p, text, mode)
                   : uxr_buffer_create_datareader_ref(s, c->out, o, p, text, mode);
    }
    printf("ERROR kind %s\n", kind);
    exit(2);
}

int main(int argc, char **argv) {
    if (argc < 4) {
        fprintf(stderr, "usage: %s udp4|udp6|tcp4|tcp6 host port | serial FD 0 < script\n", argv[0]);
        return 2;
    }
    static Client c;
    if (open_client(&c, argv[1], argv[2], argv[3], 0xE9051A00u)) return 1;
    char line[MAX_LINE];
    int number = 0, batch = 0, batched = 0;
    uint16_t requests[MAX_BATCH];
    int lines[MAX_BATCH];
    while (fgets(line, sizeof line, stdin)) {
        number++;
        line[strcspn(line, "\n")] = 0;
        if (line[0] == 0 || line[0] == '#') continue;
        if (sscanf(line, "batch %d", &batch) == 1) {
            if (batch > MAX_BATCH) batch = MAX_BATCH;
            continue;
        }
        char kind[32], format[8], mode[32];
        int id, parent, used = 0;
        if (sscanf(line, "%31s %7s %i %i %31s %n", kind, format, &id, &parent, mode, &used) < 5) {
            printf("ERROR line %d\n", number);
            return 2;
        }
        uint16_t request = buffer_create(&c, kind, format, id, parent, mode_of(mode), line + used);
        if (request == UXR_INVALID_REQUEST_ID) {
            printf("FULL %d\n", number);
            fflush(stdout);
            close_client(&c);
            return 3;
        }
        requests[batched] = request;
        lines[batched++] = number;
        if (batch > 0 && --batch > 0) continue;
        uint8_t statuses[MAX_BATCH];
        uxr_run_session_until_all_status(&c.session, 3000, requests, statuses, batched);
        for (int i = 0; i < batched; i++) printf("STATUS %d %d\n", lines[i], statuses[i]);
        fflush(stdout);
        batched = 0;
    }
    close_client(&c);
    return 0;
}
