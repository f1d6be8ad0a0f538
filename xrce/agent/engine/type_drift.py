"""Type drift: a board's samples that cannot be the type the agent has for their topic, named.

The agent moves CDR as it comes; when the board's classes were generated from another version of
a ``.msg`` than the agent's package (issue 52: ``float64 voltage`` against ``float32``, 98 of 100
samples in ROS with ``voltage 0.0`` and no word anywhere), nothing else notices. The middleware's
``sample_check(writer)`` (rclpy deserialization: ``xrce.agent.middleware.ros.sample_check``) can
tell; this module decides which samples it sees, so that checking costs nothing per sample:

- ``arm`` puts a one-shot function in the writer's ``entry.write`` at creation. The first sample
  goes through it: checked, published, and ``entry.write`` is the middleware's own publish again,
  so every later sample takes exactly the path it took before (``DataPath.fast_write``, and the
  compiled UDP path, which learns the writer from that first sample and never calls Python).
- A sample that passes re-arms the check ``RECHECK_S`` later (a timer, not a test per sample): a
  sequence or string can make a drifted type deserialize by chance once. On the compiled path the
  re-armed check waits for the next sample Python sees, so it is at most one per endpoint per
  ``RECHECK_S``, and most often none after the first.
- A sample that fails is named once per endpoint (``MismatchReport``: the board's key and
  address, the topic, the type, the fix) and counted in the stats; the endpoint is not checked
  again (its samples still go to ROS, as they did: the agent does not judge a board's data).

Types the agent carries by name have no package to compare with: not armed.

Before any sample, ``declared_hash`` compares the RIHS01 type hash a board may declare at
creation (``xrce.client.type_hash``: ``typehash=RIHS01_<hex>;``, rmw's USER_DATA form, in the
optional user data of the binary representation's EndpointQos) with the hash of this agent's
package (``middleware.type_hash``); a different one is a mismatch report like a drifted sample's,
named as the endpoint is created. Boards that declare nothing (eProsima's client,
rmw_microxrcedds: neither sends a hash) are checked by their samples only.
"""

from __future__ import annotations

import logging

from xrce.agent.engine.client import ClientProxy, ObjectEntry
from xrce.agent.observe import entities as words
from xrce.agent.observe.names import object_id_text, ros_topic_name, ros_type_name

log = logging.getLogger("xrce.agent")

RECHECK_S = 60.0  # at most one sample per endpoint per minute is deserialized for the check
FIX = ("the board's classes and the agent's package come from different definitions of the type; "
       "fix: regenerate the board's classes (xrce-client gen-msgs DIR/%s) or rebuild the agent's "
       "package (xrce-agent build-interfaces DIR --package %s) from the same .msg")


def arm(middleware, mismatches, scheduler, client: ClientProxy, entry: ObjectEntry, key) -> None:
    """Check the next sample of the datawriter ``entry`` against the middleware's type for it
    (nothing happens when the middleware cannot tell)."""
    if entry.topic_spec is None:
        return
    check = middleware.sample_check(key, entry.topic_spec.type_name)
    if check is None:
        return
    publish = entry.write

    def first_sample(sample: bytes) -> bool:
        if entry.write is first_sample:
            entry.write = publish  # the following samples go straight to the middleware again
        why = check(sample)
        if why is None:
            _recheck_later(scheduler, client, entry, first_sample, publish)
        else:
            type_name = _type(entry)
            package = type_name.split("/")[0]
            mismatches.report(client, entry, "type drift on %s: a sample the board wrote cannot be %s "
                              "as this agent has it: %s; %s" % (_topic(entry), type_name, why,
                                                                FIX % (package, package)))
        return publish(sample)

    entry.write = first_sample


def declared_hash(middleware, mismatches, client: ClientProxy, entry: ObjectEntry, qos) -> None:
    """The type hash the board declared for the datawriter or datareader ``entry`` (in ``qos``,
    the binary representation's EndpointQos, None otherwise) against this agent's package."""
    declared = _declared(getattr(qos, "user_data", None))
    if declared is None or entry.topic_spec is None:
        return
    entry.info["type_hash"] = declared
    ours = middleware.type_hash(entry.topic_spec.type_name)
    where = "client %s, %s %s: %s %s" % (client.key.hex(), words.kind_name(entry.kind),
                                         object_id_text(entry.object_id), _topic(entry), _type(entry))
    if ours is None:
        log.info("%s: the board declares type hash %s; this agent has no package of the type to "
                 "compare it with (carried by name)", where, declared)
    elif ours == declared:
        log.info("%s: type hash %s, as this agent's package", where, declared)
    else:
        package = _type(entry).split("/")[0]
        mismatches.report(client, entry, "type hash mismatch on %s: the board's classes of %s were "
                          "generated from a definition with %s, this agent's package has %s; %s"
                          % (_topic(entry), _type(entry), declared, ours, FIX % (package, package)))


def _declared(user_data) -> str | None:
    """``RIHS01_<64 hex>`` from rmw's USER_DATA form ``typehash=...;`` (other keys may be beside it)."""
    if not user_data:
        return None
    try:
        text = bytes(user_data).decode("ascii")
    except UnicodeDecodeError:
        return None
    for item in text.split(";"):
        key, _, value = item.partition("=")
        if key.strip() == "typehash" and value.startswith("RIHS01_") and len(value) == 71:
            return value
    return None


def _recheck_later(scheduler, client, entry, check_next, publish) -> None:
    loop = scheduler.loop
    if loop is None:
        return

    def rearm() -> None:
        # Still the same writer, publishing as before: its next sample is checked.
        if client.objects.get(entry.object_id) is entry and entry.write is publish:
            entry.write = check_next
    loop.call_later(RECHECK_S, rearm)


def _topic(entry: ObjectEntry) -> str:
    return ros_topic_name(entry.topic_spec.name) if entry.topic_spec is not None else "?"


def _type(entry: ObjectEntry) -> str:
    return ros_type_name(entry.topic_spec.type_name) if entry.topic_spec is not None else "?"
