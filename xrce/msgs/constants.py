# load_constants(cls): a message type's CONSTANT=value definitions (BatteryState.POWER_SUPPLY_STATUS_FULL
# ...) as attributes of its class; returns the class. CPython calls it for every type that has
# constants when the type is defined; a board only when asked:
#     from xrce.msgs.constants import load_constants
#     load_constants(BatteryState)
# They live in xrce/msgs/<package>/_<Type>_constants.py, not in the type's module: on a
# board each name a loaded module holds stays in the string pool for good (sensor_msgs/BatteryState's
# 23 names cost 1 KB of heap, as much as the class itself), so a firmware that never reads them (or
# names the values it needs as const()) does not pay for them.

import sys

from xrce import IS_MICROPYTHON
from xrce.msgs import _import


def load_constants(cls):
    package, _, name = cls.ROS_TYPE.split("/")
    dotted = "xrce.msgs.%s._%s_constants" % (package, name)
    module = _import(dotted)
    for key, value in module.__dict__.items():
        if key[0] != "_":
            setattr(cls, key, value)
    if IS_MICROPYTHON:  # the class holds the values now
        del sys.modules[dotted]
        _import("xrce.msgs." + package).__dict__.pop(dotted.rsplit(".", 1)[1], None)
    return cls
