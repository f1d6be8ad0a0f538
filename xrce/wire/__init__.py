# The DDS-XRCE wire core: the codec the client (on MicroPython) and the agent (CPython/asyncio) share.
# Its modules do no I/O and raise only xrce.DecodeError on bad bytes; they import nothing from
# xrce.client, xrce.agent, xrce.transports or xrce.tools (tests/repo/test_import_graph.py checks it).
#
# - ``cdr``: the XCDR1 reader and writer (``cdr_more``: the methods the client core never calls,
#   bound on first use).
# - ``constants``: the wire's numbers; ``names``: readable names for them (logs, tools; not shipped
#   to boards).
# - ``message``: the message header and submessage framing (``message_header``: the header as an
#   object, for the agent and the tools, loaded on first use).
# - ``streams``: best-effort and reliable stream state, with the 16-bit sequence-number arithmetic.
# - ``objects``: object ids and representations; ``payload``, ``session_payloads``,
#   ``stream_payloads``: the submessage payloads; ``submessages``: the codec of every payload by id.
#
# The error types and the CPython/MicroPython shims these modules use are the package xrce's own
# (xrce/__init__.py): every import loads that package anyway. This file holds no code: a board
# pays for the package object only.
