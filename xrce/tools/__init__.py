"""CPython-only helpers for building and packaging the client; never shipped to boards."""
