"""Round trips of the generated message classes: against rclpy's own serialization for every type
rclpy can import, and against themselves for tf2_msgs/turtlebot3_msgs (no rclpy wheels yet).

Field metadata comes from the generator's own parser (xrce.tools.msg_parser), so the hypothesis
strategies cover exactly the fields the generated code handles and the converters know each ROS
primitive.
Values are compared after decoding, never as raw bytes: rclpy leaves garbage in CDR padding.
"""

import importlib
import os
import sys

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from xrce.tools import msggen
from xrce.tools import msg_parser
from xrce.msgs import lookup

VENV_SHARE = os.path.join(sys.prefix, "share")
RCLPY_PACKAGES = msggen.SHIPPED_FROM_VENV
REPO = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def load_all_specs():
    """(registry "pkg/Type" -> spec, list of every message/request/response spec)."""
    packages = [msg_parser.load_package(d) for d in msggen.shipped_package_dirs()]
    registry = msggen.build_registry(packages)
    specs = []
    for _, messages, services in packages:
        specs.extend(messages)
        for srv in services:
            specs.extend((srv.request, srv.response))
    return registry, specs


REGISTRY, ALL_SPECS = load_all_specs()

_INT_BOUNDS = msg_parser.INT_RANGES


def _scalar(ftype):
    base = ftype.base
    if base == "bool":
        return st.booleans()
    if base == "float32":
        return st.floats(width=32, allow_nan=False, allow_infinity=False)
    if base == "float64":
        return st.floats(allow_nan=False, allow_infinity=False)
    if base == "string":
        limit = 6 if ftype.string_bound is None else min(ftype.string_bound, 6)
        return st.text(st.characters(blacklist_categories=("Cs",), blacklist_characters="\x00"), max_size=limit)
    if base in _INT_BOUNDS:
        lo, hi = _INT_BOUNDS[base]
        return st.integers(lo, hi)
    return message_values(REGISTRY[base])


def field_values(ftype):
    if ftype.array is None:
        return _scalar(ftype)
    if ftype.array == "fixed":
        lo = hi = ftype.array_size
    else:
        lo, hi = 0, 3 if ftype.array_size is None else min(ftype.array_size, 3)
    if ftype.is_primitive and msg_parser.PRIMITIVES[ftype.base][2] == "octet":
        return st.binary(min_size=lo, max_size=max(hi, lo))
    return st.lists(_scalar(ftype), min_size=lo, max_size=max(hi, lo))


def message_values(spec):
    """Strategy of nested dicts accepted by the generated class's from_dict."""
    return st.fixed_dictionaries({f.name: field_values(f.type) for f in spec.fields})


def our_class(spec):
    return lookup(spec.ros_type)


# --- rclpy side --------------------------------------------------------------------------------


def rclpy_class(spec):
    module = importlib.import_module("%s.%s" % (spec.package, spec.kind))
    return getattr(module, spec.name)


def to_rclpy(msg, spec):
    """Our message object -> equal rclpy message object."""
    out = rclpy_class(spec)()
    for f in spec.fields:
        setattr(out, f.name, _value_to_rclpy(getattr(msg, f.name), f.type))
    return out


def _value_to_rclpy(value, ftype):
    if ftype.is_nested:
        nested = REGISTRY[ftype.base]
        if ftype.array:
            return [to_rclpy(v, nested) for v in value]
        return to_rclpy(value, nested)
    if ftype.base == "byte":  # rclpy carries octets as 1-byte bytes objects
        if ftype.array:
            return [bytes([b]) for b in value]
        return bytes([value])
    if ftype.array and ftype.base in ("uint8", "char"):
        return list(value)
    return value


def from_rclpy(rmsg, spec):
    """rclpy message object -> our message object."""
    values = {}
    for f in spec.fields:
        values[f.name] = _value_from_rclpy(getattr(rmsg, f.name), f.type)
    return our_class(spec)(**values)


def _plain(x):
    return x.item() if hasattr(x, "item") else x


def _value_from_rclpy(value, ftype):
    if ftype.is_nested:
        nested = REGISTRY[ftype.base]
        if ftype.array:
            return [from_rclpy(v, nested) for v in value]
        return from_rclpy(value, nested)
    if ftype.base == "byte":
        if ftype.array:
            return b"".join(value)
        return value[0]
    if ftype.array:
        if ftype.base in ("uint8", "char"):
            return bytes(bytearray(int(x) for x in value))
        return [_plain(x) for x in value]
    return _plain(value)


# --- the tests ---------------------------------------------------------------------------------

CDR_LE_HEADER = b"\x00\x01\x00\x00"
RCLPY_SPECS = [s for s in ALL_SPECS if s.package in RCLPY_PACKAGES]
OWN_SPECS = [s for s in ALL_SPECS if s.package not in RCLPY_PACKAGES]
FAST = settings(max_examples=30, deadline=None, derandomize=True,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])


def test_every_shipped_package_is_covered():
    packages = set(s.package for s in ALL_SPECS)
    assert packages == set(msggen.SHIPPED_FROM_VENV + msggen.SHIPPED_FROM_REPO)
    assert len(RCLPY_SPECS) > 100


@pytest.mark.parametrize("spec", RCLPY_SPECS, ids=lambda s: s.ros_type)
def test_matches_rclpy_serialization(spec):
    from rclpy.serialization import deserialize_message, serialize_message

    cls = our_class(spec)
    rcls = rclpy_class(spec)

    @FAST
    @given(message_values(spec))
    def check(values):
        ours = cls.from_dict(values)
        # ours -> rclpy: rclpy must read back exactly our values
        decoded_by_rclpy = deserialize_message(CDR_LE_HEADER + ours.to_bytes(), rcls)
        assert from_rclpy(decoded_by_rclpy, spec) == ours
        # rclpy -> ours: strip the encapsulation header as the XRCE agent does
        data = serialize_message(to_rclpy(ours, spec))
        assert data[:4] == CDR_LE_HEADER
        assert cls.from_bytes(data[4:]) == ours

    check()


@pytest.mark.parametrize("spec", OWN_SPECS, ids=lambda s: s.ros_type)
def test_self_round_trip(spec):
    cls = our_class(spec)

    @FAST
    @given(message_values(spec))
    def check(values):
        ours = cls.from_dict(values)
        body = ours.to_bytes()
        assert cls.from_bytes(body) == ours
        assert cls.from_bytes(body + b"\x00\x00\x00") == ours  # DDS tail padding is tolerated
        assert cls.from_dict(ours.to_dict()) == ours

    check()
