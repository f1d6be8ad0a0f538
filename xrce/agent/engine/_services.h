/* What the compiled helper's files share (the module is built from _fastpath.c, _services.c). */
#ifndef XRCE_ENGINE_SERVICES_H
#define XRCE_ENGINE_SERVICES_H

#include <Python.h>

/* Adds _services.c's functions (raw_request_conversion, raw_reply_conversion) to the module. */
int xrce_services_add(PyObject *module);

#endif
