# Conversion between messages and nested dicts/lists, loaded only when first used.
#
# A class's field shapes come from its field specs (_S, see __init__.py): a nested message, a list
# of messages, bytes (octet arrays), or a plain value.

from xrce import EncodeError
from xrce.msgs import _PACK_ERRORS

_VALUE, _NESTED, _NESTED_LIST, _BYTES = 0, 1, 2, 3

_shapes = {}


# ((field name, kind, nested class or None), ...) for `cls`.
def _shape(cls):
    shape = _shapes.get(cls)
    if shape is None:
        entries = []
        for name, spec in zip(cls.__slots__, cls._S):
            if type(spec) is tuple and spec[0] != "s":
                item = spec[2]
                if item == "B":
                    entries.append((name, _BYTES, None))
                elif type(item) is not str and type(item) is not tuple:
                    entries.append((name, _NESTED_LIST, item))
                else:
                    entries.append((name, _VALUE, None))
            elif type(spec) is not str and type(spec) is not tuple:
                entries.append((name, _NESTED, spec))
            else:
                entries.append((name, _VALUE, None))
        shape = tuple(entries)
        _shapes[cls] = shape
    return shape


def to_dict(msg):
    out = {}
    for name, kind, _ in _shape(type(msg)):
        value = getattr(msg, name)
        if kind == _NESTED:
            value = to_dict(value)
        elif kind == _NESTED_LIST:
            value = [to_dict(item) for item in value]
        elif kind == _VALUE and isinstance(value, list):
            value = list(value)
        out[name] = value
    return out


def from_dict(cls, d):
    if isinstance(d, cls):
        return d
    if not isinstance(d, dict):
        raise EncodeError("%s: expected a dict, got %r" % (cls.ROS_TYPE, d))
    msg = cls()
    shape = _shape(cls)
    for key, value in d.items():
        for name, kind, ref in shape:
            if name == key:
                break
        else:
            raise EncodeError("%s has no field %r" % (cls.ROS_TYPE, key))
        if kind == _NESTED:
            value = from_dict(ref, value)
        elif kind == _NESTED_LIST:
            if not isinstance(value, (list, tuple)):
                raise EncodeError("%s.%s: expected a list, got %r" % (cls.ROS_TYPE, key, value))
            value = [from_dict(ref, item) for item in value]
        elif kind == _BYTES:
            if not isinstance(value, (bytes, bytearray)):
                try:
                    value = bytes(value)
                except _PACK_ERRORS:
                    raise EncodeError("%s.%s: expected bytes, got %r" % (cls.ROS_TYPE, key, value))
        elif isinstance(value, tuple):
            value = list(value)
        setattr(msg, name, value)
    return msg
