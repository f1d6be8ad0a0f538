# lookup(): message and service classes by ROS or DDS type name, loaded by the first call of
# xrce.msgs.lookup. Only the looked-up type's module is imported. Comments
# rather than docstrings: MicroPython keeps docstring text in the heap when compiling from source.

from xrce.msgs import _import

_cache = {}


def _is_name(text):
    if not text or text[0] == "_":
        return False
    for ch in text:
        if not (ch == "_" or "a" <= ch <= "z" or "A" <= ch <= "Z" or "0" <= ch <= "9"):
            return False
    return True


# The class for "pkg/msg/Type", "pkg/Type", "pkg::msg::dds_::Type_" or "pkg/srv/Srv" (the service
# descriptor; "pkg/srv/Srv_Request" and "pkg::srv::dds_::Srv_Request_" name its request).
# Raises KeyError for names that are malformed or not generated.
def lookup(type_name):
    cls = _cache.get(type_name)
    if cls is not None:
        return cls
    if "::" in type_name:
        parts = type_name.split("::")
        if len(parts) != 4 or parts[2] != "dds_" or not parts[3].endswith("_"):
            raise KeyError(type_name)
        package, name, check = parts[0], parts[3][:-1], "TYPE_NAME"
    else:
        parts = type_name.split("/")
        if len(parts) == 3:
            package, name, check = parts[0], parts[2], "ROS_TYPE"
        elif len(parts) == 2:
            package, name, check = parts[0], parts[1], None
        else:
            raise KeyError(type_name)
    if not (_is_name(package) and _is_name(name)):
        raise KeyError(type_name)
    try:
        module = _import("xrce.msgs." + package)
        services = module._SERVICE_CLASSES
    except (ImportError, AttributeError):  # no such package, or not a generated one
        raise KeyError(type_name)
    if check == "ROS_TYPE" and parts[1] == "srv" and name not in services and name + "_Service" in services:
        name += "_Service"  # the descriptor's name when a message of the package took the plain one
    try:
        cls = getattr(module, name)
    except AttributeError:
        raise KeyError(type_name)
    if check is None:  # "pkg/Name": anything the package defines, as long as it is a type
        ros_type = getattr(cls, "ROS_TYPE", None)
        if not isinstance(ros_type, str) or ros_type[ros_type.rfind("/") + 1:] != parts[1]:
            raise KeyError(type_name)
    elif getattr(cls, check, None) != type_name:
        raise KeyError(type_name)
    _cache[type_name] = cls
    return cls


# SERVICES of a generated package (`namespace` is its globals): service name -> descriptor. Imports
# every service module of the package, which is why it is built only when asked for.
def services_table(namespace):
    table = {}
    for class_name in namespace["_SERVICE_CLASSES"]:
        descriptor = getattr(_import(namespace["__name__"] + "._" + class_name), class_name)
        ros_type = descriptor.ROS_TYPE
        if "/action/" in ros_type:
            continue  # an action's descriptor (listed with the services: see msggen)
        table[ros_type[ros_type.rfind("/") + 1:]] = descriptor
    return table


# A package's SERVICES, or "Name_Request"/"Name_Response": the module of service Name (whose
# descriptor class may be "Name_Service", see msggen.service_class_name), else a message module of
# that name. Called by xrce.msgs._type_attr.
def service_attr(namespace, name):
    if name == "SERVICES":
        return services_table(namespace)
    module = name
    cut = name.rfind("_")
    services = namespace["_SERVICE_CLASSES"]
    base = name[:cut]
    action = name[:name.find("_")]
    if base in services:
        module = base
    elif base + "_Service" in services:
        module = base + "_Service"
    elif action in services or action + "_Action" in services:
        # An action's types (Name_Goal, Name_SendGoal_Request, ...) live in the action's module.
        module = action if action in services else action + "_Action"
    try:
        return getattr(_import(namespace["__name__"] + "._" + module), name)
    except ImportError:
        raise AttributeError(name)
