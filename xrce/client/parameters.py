# A ROS 2 parameter server on a client node, as rclc_parameter gives micro-ROS firmware: integer,
# double, bool and string parameters declared at set-up with defaults, optionally read-only or
# bounded by a range, reached by `ros2 param list/get/set/describe/dump` through the six
# rcl_interfaces services under the node's name and announced on /parameter_events.
#
#     params = ParameterServer(session, node, "/tb3_fw", on_change=check)
#     params.declare("wheel_radius", 0.033, min_value=0.01, max_value=0.1)
#     params.declare("motor_kp", 120)
#     session.run_until_all_status(1000)
#     ... params["motor_kp"] in the firmware's loop; the session's spinning answers the services.
#
# ``on_change(name, value)`` runs before a remote set takes effect: None or True accepts it,
# False rejects it with rclc's "Rejected by server", a string rejects it with that string as the
# reason the caller sees.
#
# Names, types and QoS are rmw_microxrcedds' and rclc's (tests/golden/microros/actions_params.jsonl):
# repliers '/<node>/get_parameters' ... 'describe_parameters' with 'rq/<node>/<service>Request' and
# 'rr/...Reply', and 'rt/parameter_events' reliable, keep-last 1000; an event names the node by its
# base name, one per declared parameter (new_parameters) and per accepted set (changed_parameters).
# The reasons a set is refused are rclc's ("Parameter not found", "Read only parameter", "Type
# mismatch", "Rejected by server"), with "Value out of range" where rclc says "Set parameter error".
# Unlike rclc, set_parameters_atomically is served (all or nothing) and string parameters exist.
#
# A board loads this module only when it makes a parameter server (bench/micropython/client_footprint.py states
# its cost); the rcl_interfaces classes load with it.

from xrce import const
from xrce.msgs import rcl_interfaces

_NOT_SET = const(0)
_BOOL = const(1)
_INTEGER = const(2)
_DOUBLE = const(3)
_STRING = const(4)
_EVENT_DEPTH = const(1000)  # rmw_qos_profile_parameter_events, as rclc creates the writer

# The field of ParameterValue that holds each type's value, by type number.
_VALUE_FIELDS = (None, "bool_value", "integer_value", "double_value", "string_value")
_SERVICES = ("get_parameters", "get_parameter_types", "set_parameters", "set_parameters_atomically",
             "list_parameters", "describe_parameters")


def _type_of(value):
    # bool before int: True is an int to Python.
    if isinstance(value, bool):
        return _BOOL
    if isinstance(value, int):
        return _INTEGER
    if isinstance(value, float):
        return _DOUBLE
    if isinstance(value, str):
        return _STRING
    raise TypeError("parameters are bool, int, float or str")


class ParameterServer:
    # The parameters of node ``node_id`` (a participant), named ``node_name`` ('/tb3_fw' or
    # '/ns/tb3_fw', as the participant was created). At most ``max_params`` parameters; a request
    # naming more than that is answered empty, as rclc does.

    def __init__(self, session, node_id, node_name, on_change=None, max_params=8, events=True,
                 stream_id=None):
        if not node_name.startswith("/"):
            node_name = "/" + node_name
        self.session = session
        self.node_name = node_name
        self.on_change = on_change
        self.max_params = max_params
        self.stream_id = stream_id
        # name -> [value, type, read_only, (min, max, step) or None, description]
        self._params = {}
        self._order = []  # declaration order, which list_parameters answers in
        self.events_writer = None
        if events:
            self.events_writer = session.create_writer(node_id, "/parameter_events",
                                                       rcl_interfaces.ParameterEvent, reliable=True,
                                                       depth=_EVENT_DEPTH, stream_id=stream_id)
        handlers = (self._get, self._get_types, self._set, self._set_atomically, self._list,
                    self._describe)
        srv_classes = (rcl_interfaces.GetParameters, rcl_interfaces.GetParameterTypes,
                       rcl_interfaces.SetParameters, rcl_interfaces.SetParametersAtomically,
                       rcl_interfaces.ListParameters, rcl_interfaces.DescribeParameters)
        self.repliers = []
        for i in range(len(_SERVICES)):
            replier = session.create_service_server(node_id, node_name + "/" + _SERVICES[i],
                                                    srv_classes[i], self._answer(i, handlers[i]),
                                                    stream_id=stream_id)
            self.repliers.append(replier)

    def _answer(self, index, handler):
        # The callback of replier ``index``: ``handler(request)`` builds the response, sent at once.
        def callback(sample_identity, request):
            self.session.send_reply(self.repliers[index], sample_identity, handler(request),
                                    self.stream_id)
        return callback

    # ------------------------------------------------------------------ the firmware's side

    def declare(self, name, default, read_only=False, min_value=None, max_value=None, step=0,
                description=""):
        # A parameter with its default; ``min_value``/``max_value`` bound an int or float one
        # (``step`` as rcl_interfaces' ranges: 0 for any value in the range).
        if name in self._params:
            raise ValueError("parameter %s is declared already" % name)
        if len(self._order) >= self.max_params:
            raise ValueError("parameter server is full (max_params=%d)" % self.max_params)
        kind = _type_of(default)
        bounds = None
        if min_value is not None or max_value is not None:
            if kind != _INTEGER and kind != _DOUBLE:
                raise ValueError("only int and float parameters take a range")
            bounds = (min_value, max_value, step)
        self._params[name] = [default, kind, read_only, bounds, description]
        self._order.append(name)
        self._publish_event(name, True)

    def __getitem__(self, name):
        return self._params[name][0]

    def get(self, name, default=None):
        entry = self._params.get(name)
        return default if entry is None else entry[0]

    def set(self, name, value):
        # Set from the firmware itself: checked like a remote set (read-only excepted) but never
        # offered to on_change; announced on /parameter_events. Returns None or the reason it failed.
        reason = self._check(name, value, False)
        if reason is None:
            self._params[name][0] = value
            self._publish_event(name, False)
        return reason

    def names(self):
        return list(self._order)

    # ------------------------------------------------------------------ checks and events

    def _check(self, name, value, remote):
        entry = self._params.get(name)
        if entry is None:
            return "Parameter not found"
        if remote and entry[2]:
            return "Read only parameter"
        try:
            kind = _type_of(value)
        except TypeError:
            return "Type not supported"
        if kind != entry[1]:
            return "Type mismatch"
        bounds = entry[3]
        if bounds is not None:
            low, high, step = bounds
            if (low is not None and value < low) or (high is not None and value > high):
                return "Value out of range"
            if step and low is not None and kind == _INTEGER and (value - low) % step:
                return "Value out of range"
        return None

    def _offer(self, name, value):
        # on_change's verdict on a remote set: None when accepted, else the reason.
        if self.on_change is None:
            return None
        verdict = self.on_change(name, value)
        if verdict is None or verdict is True:
            return None
        return verdict if isinstance(verdict, str) else "Rejected by server"

    def _publish_event(self, name, new):
        if self.events_writer is None:
            return
        event = rcl_interfaces.ParameterEvent()
        stamp = self.session.epoch_ns()
        event.stamp.sec = stamp // 1000000000
        event.stamp.nanosec = stamp % 1000000000
        event.node = self.node_name[self.node_name.rfind("/") + 1:]  # rclc's: the base name
        parameter = self._parameter(name)
        if new:
            event.new_parameters = [parameter]
        else:
            event.changed_parameters = [parameter]
        self.session.write(self.events_writer, event, self.stream_id)

    def _value(self, name):
        value = rcl_interfaces.ParameterValue()
        entry = self._params.get(name)
        if entry is not None:
            value.type = entry[1]
            setattr(value, _VALUE_FIELDS[entry[1]], entry[0])
        return value

    def _parameter(self, name):
        return rcl_interfaces.Parameter(name=name, value=self._value(name))

    def _too_many(self, names):
        return len(names) > self.max_params

    # ------------------------------------------------------------------ the six services

    def _get(self, request):
        response = rcl_interfaces.GetParameters.Response()
        if not self._too_many(request.names):
            response.values = [self._value(name) for name in request.names]
        return response

    def _get_types(self, request):
        response = rcl_interfaces.GetParameterTypes.Response()
        if not self._too_many(request.names):
            types = []
            for name in request.names:
                entry = self._params.get(name)
                types.append(_NOT_SET if entry is None else entry[1])
            response.types = types
        return response

    def _remote_value(self, parameter):
        # The Python value a request's Parameter carries, or None for a type this server lacks.
        kind = parameter.value.type
        if kind < _BOOL or kind > _STRING:
            return None
        return getattr(parameter.value, _VALUE_FIELDS[kind])

    def _verdict(self, parameter):
        name = parameter.name
        if parameter.value.type == _NOT_SET and name in self._params:
            return "Parameters cannot be undeclared"
        value = self._remote_value(parameter)  # None: "Type not supported" (or read-only) below
        reason = self._check(name, value, True)
        if reason is None:
            reason = self._offer(name, value)
        return reason

    def _set(self, request):
        response = rcl_interfaces.SetParameters.Response()
        if self._too_many(request.parameters):
            return response
        results = []
        for parameter in request.parameters:
            reason = self._verdict(parameter)
            if reason is None:
                self._params[parameter.name][0] = self._remote_value(parameter)
                self._publish_event(parameter.name, False)
            results.append(rcl_interfaces.SetParametersResult(successful=reason is None,
                                                               reason=reason or ""))
        response.results = results
        return response

    def _set_atomically(self, request):
        response = rcl_interfaces.SetParametersAtomically.Response()
        result = response.result
        if self._too_many(request.parameters):
            result.reason = "Too many parameters"
            return response
        for parameter in request.parameters:
            reason = self._verdict(parameter)
            if reason is not None:
                result.reason = "%s: %s" % (parameter.name, reason)
                return response
        for parameter in request.parameters:
            self._params[parameter.name][0] = self._remote_value(parameter)
            self._publish_event(parameter.name, False)
        result.successful = True
        return response

    def _list(self, request):
        # rcl's rules: a name is listed when no prefix is given or it is a prefix or lies under one
        # ('a.b' under 'a'), and, for a depth other than 0 (recursive), when it has fewer than
        # ``depth`` dot-separated levels below where it was matched.
        response = rcl_interfaces.ListParameters.Response()
        names = []
        prefixes = []
        depth = request.depth
        for name in self._order:
            matched = not request.prefixes
            below = name
            for prefix in request.prefixes:
                if name == prefix or name.startswith(prefix + "."):
                    matched = True
                    below = name[len(prefix) + 1:]
                    break
            if not matched or (depth and below.count(".") >= depth):
                continue
            names.append(name)
            cut = name.rfind(".")
            if cut > 0 and name[:cut] not in prefixes:
                prefixes.append(name[:cut])
        response.result.names = names
        response.result.prefixes = prefixes
        return response

    def _describe(self, request):
        response = rcl_interfaces.DescribeParameters.Response()
        if self._too_many(request.names):
            return response
        descriptors = []
        for name in request.names:
            descriptor = rcl_interfaces.ParameterDescriptor(name=name)
            entry = self._params.get(name)
            if entry is not None:
                descriptor.type = entry[1]
                descriptor.read_only = entry[2]
                descriptor.description = entry[4]
                bounds = entry[3]
                if bounds is not None:
                    kind = entry[1]
                    limits = rcl_interfaces.IntegerRange() if kind == _INTEGER else rcl_interfaces.FloatingPointRange()
                    # An open side is sent as infinity, not the largest double: a single-precision
                    # board holds no float past 3.4e38 (the largest double read as inf there anyway), and
                    # MicroPython's freezer packs every float constant as 32 bits and stops on one.
                    wide = 0x7FFFFFFFFFFFFFFF if kind == _INTEGER else float("inf")
                    limits.from_value = -wide if bounds[0] is None else bounds[0]
                    limits.to_value = wide if bounds[1] is None else bounds[1]
                    limits.step = bounds[2]
                    if kind == _INTEGER:
                        descriptor.integer_range = [limits]
                    else:
                        descriptor.floating_point_range = [limits]
            descriptors.append(descriptor)
        response.descriptors = descriptors
        return response
