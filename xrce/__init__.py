"""xrce: a Python implementation of the DDS-XRCE wire protocol as spoken by eProsima Micro XRCE-DDS.

The modules directly under this package are the wire core shared by the client (which must run on
MicroPython) and the agent (CPython/asyncio): they do no I/O and raise only ``DecodeError`` on bad
bytes.
"""

__version__ = "0.1.0"
