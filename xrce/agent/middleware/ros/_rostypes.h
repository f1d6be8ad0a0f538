/* What the files of the ROS type-support extension (xrce.agent.middleware.ros._rostypes) share:
 * _rostypes.c makes the module and adds _services.c's and _named_types.c's functions to it. */
#ifndef XRCE_ROSTYPES_H
#define XRCE_ROSTYPES_H

#include <Python.h>

/* Adds _services.c's functions (raw_request_conversion, raw_reply_conversion) to the module. */
int xrce_services_add(PyObject *module);

/* Adds _named_types.c's functions (type supports of types known only by name). */
int xrce_named_types_add(PyObject *module);

/* A function of rcl, rmw or rcutils from the librcl rclpy loaded; NULL without one. */
void *xrce_rcl_symbol(const char *name);

typedef void (*reset_error_fn)(void);

#endif
