/* The ROS structures the type supports of types known by name are made of (_named_types.c),
 * declared as rosidl_runtime_c, rosidl_typesupport_fastrtps_cpp and
 * rosidl_typesupport_introspection_c declare them in the headers of Jazzy's and Kilted's wheels
 * (the same in both); nothing of ROS is linked or included. */
#ifndef XRCE_ROSTYPES_NAMED_TYPES_H
#define XRCE_ROSTYPES_NAMED_TYPES_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

typedef struct { uint8_t version; uint8_t value[32]; } type_hash_t;  /* version 0: unset */
typedef struct { char *data; size_t size, capacity; } ros_string_t;
typedef struct { void *data; size_t size, capacity; } ros_sequence_t;
typedef struct { ros_string_t type_name; ros_sequence_t fields; } individual_description_t;
typedef struct { individual_description_t type; ros_sequence_t referenced; } type_description_t;

typedef struct message_ts message_ts_t;
struct message_ts {  /* rosidl_message_type_support_t */
    const char *identifier;
    const void *data;
    const message_ts_t *(*func)(const message_ts_t *, const char *);
    const type_hash_t *(*get_type_hash)(const message_ts_t *);
    const type_description_t *(*get_type_description)(const message_ts_t *);
    const ros_sequence_t *(*get_type_description_sources)(const message_ts_t *);
};

typedef struct service_ts service_ts_t;
struct service_ts {  /* rosidl_service_type_support_t */
    const char *identifier;
    const void *data;
    const service_ts_t *(*func)(const service_ts_t *, const char *);
    const message_ts_t *request, *response, *event;
    void *(*event_create)(void);  /* never called: introspection is not enabled */
    bool (*event_destroy)(void);
    const type_hash_t *(*get_type_hash)(const service_ts_t *);
    const type_description_t *(*get_type_description)(const service_ts_t *);
    const ros_sequence_t *(*get_type_description_sources)(const service_ts_t *);
};

typedef struct {  /* message_type_support_callbacks_t (rosidl_typesupport_fastrtps_cpp) */
    const char *message_namespace, *message_name;
    bool (*cdr_serialize)(const void *message, void *cdr);
    bool (*cdr_deserialize)(void *cdr, void *message);
    uint32_t (*get_serialized_size)(const void *message);
    size_t (*max_serialized_size)(char *bounds_info);
    void *key_callbacks;
} fastrtps_callbacks_t;
#define FASTRTPS_UNBOUNDED_TYPE 0x00

typedef struct {  /* service_type_support_callbacks_t */
    const char *service_namespace, *service_name;
    const message_ts_t *request_members, *response_members;
} fastrtps_service_callbacks_t;

typedef struct {  /* rosidl_typesupport_introspection_c__MessageMembers */
    const char *message_namespace, *message_name;
    uint32_t member_count;
    size_t size_of;
    bool has_any_key_member;
    const void *members;
    void (*init_function)(void *, int);
    void (*fini_function)(void *);
} introspection_members_t;

typedef struct {  /* rosidl_typesupport_introspection_c__ServiceMembers */
    const char *service_namespace, *service_name;
    const introspection_members_t *request_members, *response_members, *event_members;
} introspection_service_members_t;

#endif
