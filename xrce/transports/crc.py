# CRC-16 functions for stream framing (XRCE-WIRE.md §11).
#
# The XRCE wire uses CRC-16/ARC (poly 0x8005 reflected, init 0, xorout 0, check 0xBB3D) over the
# unescaped payload. CRC-16/X.25 (the HDLC/PPP FCS, check 0x906E) is offered for links that want the
# HDLC flavour; both ends must agree, so "arc" is the default everywhere.
#
# On CPython crcmod is used (its C extension is several times faster than any Python loop); on
# MicroPython, or when crcmod is missing, a 256-entry table loop is used. Both are always importable
# under their own names so tests can compare them.

try:
    from array import array
except ImportError:  # pragma: no cover - every MicroPython port we target has array
    array = None


def _make_reflected_table(poly_reflected):
    table = [0] * 256
    for index in range(256):
        value = index
        for _ in range(8):
            if value & 1:
                value = (value >> 1) ^ poly_reflected
            else:
                value >>= 1
        table[index] = value
    # array("H") keeps the table at 512 bytes on MicroPython instead of 256 boxed ints.
    return array("H", table) if array is not None else tuple(table)


_ARC_TABLE = _make_reflected_table(0xA001)
_X25_TABLE = None  # built by the first X.25 frame: the wire's default is ARC (512 bytes on a board)


def crc16_arc_table(data, crc=0):
    # CRC-16/ARC of ``data`` (bytes-like), continuing from ``crc``; pure-Python table version.
    table = _ARC_TABLE
    for byte in data:
        crc = (crc >> 8) ^ table[(crc ^ byte) & 0xFF]
    return crc


def crc16_x25_table(data):
    # CRC-16/X.25 of ``data`` (bytes-like); pure-Python table version.
    global _X25_TABLE
    table = _X25_TABLE
    if table is None:
        table = _X25_TABLE = _make_reflected_table(0x8408)
    crc = 0xFFFF
    for byte in data:
        crc = (crc >> 8) ^ table[(crc ^ byte) & 0xFF]
    return crc ^ 0xFFFF


try:
    import crcmod.predefined as _crcmod_predefined
except ImportError:  # MicroPython, or CPython without crcmod
    _crcmod_predefined = None

if _crcmod_predefined is not None:
    _crcmod_arc = _crcmod_predefined.mkPredefinedCrcFun("crc-16")
    _crcmod_x25 = _crcmod_predefined.mkPredefinedCrcFun("x-25")
    HAVE_CRCMOD = True
    # Bound directly (no wrapper) to save a Python call per frame; crcmod's signature is
    # fn(data, crc=initial), so crc16_arc(data, crc) continues a running CRC like the table version.
    crc16_arc = _crcmod_arc
    crc16_x25 = _crcmod_x25

else:
    HAVE_CRCMOD = False
    crc16_arc = crc16_arc_table
    crc16_x25 = crc16_x25_table


CRC_FUNCTIONS = {"arc": crc16_arc, "ccitt": crc16_x25}


def crc_of_prefix(crc, buf, length):
    # ``crc(buf[:length])`` without the slice, which a board makes as a heap object: the table loop
    # for the two named CRCs (whichever implementation ``crc`` is), a slice for any other function.
    global _X25_TABLE
    if crc is crc16_arc or crc is crc16_arc_table:
        table = _ARC_TABLE
        value = flip = 0
    elif crc is crc16_x25 or crc is crc16_x25_table:
        table = _X25_TABLE
        if table is None:
            table = _X25_TABLE = _make_reflected_table(0x8408)
        value = flip = 0xFFFF
    else:
        return crc(memoryview(buf)[:length])
    for i in range(length):
        value = (value >> 8) ^ table[(value ^ buf[i]) & 0xFF]
    return value ^ flip


def get_crc(name_or_function="arc"):
    # The CRC function for a name in CRC_FUNCTIONS ("arc", "ccitt"), or a callable passed through.
    if callable(name_or_function):
        return name_or_function
    try:
        return CRC_FUNCTIONS[name_or_function]
    except KeyError:
        raise ValueError("unknown CRC %r (known: arc, ccitt)" % (name_or_function,))
