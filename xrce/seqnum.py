# 16-bit serial-number arithmetic (XRCE-WIRE.md §1), identical on both sides.

from xrce.compat import const

SEQ_MODULO = const(0x10000)
_HALF = const(0x8000)


def seq_add(seq, delta):
    return (seq + delta) & 0xFFFF


def seq_sub(a, b):
    # Distance from b forward to a, in 0..65535.
    return (a - b) & 0xFFFF


def seq_less(a, b):
    # True if a precedes b in serial-number order.
    if a == b:
        return False
    return (a < b and b - a < _HALF) or (a > b and a - b > _HALF)
