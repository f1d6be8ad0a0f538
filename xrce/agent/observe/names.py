"""How what others can read names a client and where it sends from: the stats port, the
``-v 5`` summary, ``/diagnostics``, capture files and the ROS node names of unnamed participants.

Only the standard library: the engine (session log lines, admission) and the middleware name
clients this way too, and the capture writer without the rest of observability.
"""

import os

try:  # the BLAKE2 core alone: hashlib would load OpenSSL for nothing
    from _blake2 import blake2b
except ImportError:
    from hashlib import blake2b

# A client key is the only credential of an XRCE session: with it, anyone who can send a
# datagram to the agent can delete or take over that session. What others can read (/diagnostics:
# the whole ROS domain; the stats port: any local user; capture files, which travel with bug
# reports) names a client by a tag instead: the first 4 bytes of BLAKE2b keyed with a secret drawn
# at agent start. Keyed, because a key has only 2**32 values: a plain hash prefix is undone by
# hashing them all, in minutes. Per run, because the secret is never stored: the same client has
# the same tag for the agent's whole run (and its capture files), a new one after a restart. The
# operator's log names the key with its tag when the session is created, as a lookup table.
_TAG_SECRET = os.urandom(16)


def client_pseudonym(key: bytes) -> bytes:
    """4 bytes that stand for client ``key`` in what others can read (see above)."""
    return blake2b(bytes(key), digest_size=4, key=_TAG_SECRET).digest()


def client_tag(key: bytes) -> str:
    """``client_pseudonym`` as 8 hex digits: how stats, /diagnostics and node names show a key."""
    return client_pseudonym(key).hex()


def endpoint_text(endpoint) -> str:
    """A link endpoint as one word (capture files split on spaces). An IPv6 address goes in
    brackets, as in a URL: its own colons would run into the port's otherwise (a link-local
    one keeps its ``%scope``, which the socket puts in the host)."""
    if isinstance(endpoint, tuple) and len(endpoint) >= 2:
        host = endpoint[0]
        return ("[%s]:%s" if ":" in str(host) else "%s:%s") % (host, endpoint[1])
    return str(endpoint).replace(" ", "")
