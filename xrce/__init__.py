# xrce: a Python implementation of the DDS-XRCE wire protocol as spoken by eProsima Micro XRCE-DDS.
#
# The modules directly under this package are the wire core shared by the client (which must run on
# MicroPython) and the agent (CPython/asyncio): they do no I/O and raise only ``DecodeError`` on bad
# bytes.
#
# Modules that run on boards explain themselves in comments, not docstrings: MicroPython keeps what
# it compiles from a docstring on the heap (5.3 KB on the String + Twist client from .py, measured
# with bench/client_footprint.py).

__version__ = "0.1.0"
