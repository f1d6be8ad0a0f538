/* What the compiled helper's ROS side shares (_services.c, _ros_support.c; _fastpath.c adds their
 * functions to the module). */
#ifndef XRCE_ENGINE_SERVICES_H
#define XRCE_ENGINE_SERVICES_H

#include <Python.h>

/* Adds _services.c's functions (raw_request_conversion, raw_reply_conversion) to the module. */
int xrce_services_add(PyObject *module);

/* Adds _ros_support.c's functions (type supports, raw conversions, participant_node, ...). */
int xrce_ros_support_add(PyObject *module);

/* Adds _named_types.c's functions (type supports of types known only by name). */
int xrce_named_types_add(PyObject *module);

/* A function of rcl, rmw or rcutils from the librcl rclpy loaded; NULL without one. */
void *xrce_rcl_symbol(const char *name);

typedef void (*reset_error_fn)(void);

#endif
