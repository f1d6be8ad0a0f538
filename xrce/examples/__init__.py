# Example firmware built on the XRCE client (MicroPython-safe, like the client itself).
pass
