# 16-bit serial-number arithmetic (XRCE-WIRE.md §1). The functions live in xrce.wire.streams, their only
# user in the client, which spares a board this module; this name stays for code that imports it.

from xrce.wire.streams import seq_add, seq_less, seq_sub  # noqa: F401

SEQ_MODULO = 0x10000
