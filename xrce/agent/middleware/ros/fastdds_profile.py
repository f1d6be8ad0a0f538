"""The Fast DDS profile ``xrce-agent`` uses when the user has none (``fastdds_profile.xml``).

Memory: Fast DDS preallocates its send buffers when the participant is created: three plus one
per receive thread, each of the largest message size (64 KB) and zero-filled, so all of them are
resident memory (640 KB of the agent's ~51 MB under the TurtleBot3 load) although a process sends
from only a few threads. The profile asks for one and lets Fast DDS add one when a thread finds
none free (``SendBuffersAllocationAttributes``: preallocated_number 1, dynamic).

Discovery (issue 22, ``bench/restart/discovery.py``, ``bench/restart/dds_rediscovery.py``): a Fast DDS 2.14
participant sends its first announcement before its receivers are attached, so a peer's answer
that comes back within that moment (0.4-3 ms under LOCALHOST, one datagram to each of 32 ports)
is dropped, and the peer never answers again: it already knows the participant. Who loses what
depends on the start order:

- a ROS node started while the agent is up loses the agent's answer, and learns of the agent only
  at the agent's next periodic announcement. The profile makes that period 0.5 s instead of 3 s
  (``leaseAnnouncement``): first sample within 1 s where it took up to 3 s;
- the agent started while ROS nodes are up loses their answers, and would wait for their periodic
  announcements (3 s, theirs to choose). The profile makes the agent's builtin writers
  asynchronous (a ``throughputController`` with 0 bytes per period: Fast DDS's unlimited
  asynchronous flow controller, no periodic wake-up), so the first announcement leaves from the
  sender thread after the receivers are attached; the answers arrive and are kept (0 of 8
  restarted participants waited, against 5 of 8 with the defaults; the sender thread can still
  beat the receivers now and then: 3 of 110 agent starts next to a busy rclpy publisher waited,
  bench/restart/discovery.py order d-b). The agent's topic writers stay synchronous: rmw_fastrtps
  creates them so and Fast DDS leaves synchronous writers out of a participant's throughput
  controller.

Cost (idle agent next to one rclpy node, medians of 3, ``bench/restart/discovery.py --idle-cost``): the
agent 0.05 -> 0.13 % of a core, the rclpy node unchanged (0.04-0.05 %), loopback 21 -> 67
datagrams/s (11 -> 35 KB/s): each announcement goes to 32 local ports under LOCALHOST, to one
multicast group under SUBNET. Transports, QoS, ports and the 20 s lease stay as rmw_fastrtps and
Fast DDS make them.

Fast DDS 3 (ROS 2 Kilted) no longer knows ``throughputController`` (an ``XMLPARSER`` error, and the
whole profile is dropped) and reads only ``FASTDDS_DEFAULT_PROFILES_FILE`` (rmw_fastrtps still
passes ``FASTRTPS_DEFAULT_PROFILES_FILE`` on, with a deprecation warning). So each major version
gets its own file, through its own variable: ``fastdds_profile.xml`` through
``FASTRTPS_DEFAULT_PROFILES_FILE`` for Fast DDS 2.x (Jazzy), ``fastdds3_profile.xml`` (a flow
controller list and the builtin writers' ``flow_controller_name``, Fast DDS 3's way to make them
asynchronous) through ``FASTDDS_DEFAULT_PROFILES_FILE`` for 3.x. The version is the one the RMW
loaded (``env.fastdds_major``).

It goes in only when nothing says the user configures Fast DDS themselves: no profiles file in
either variable, no ``DEFAULT_FASTRTPS_PROFILES.xml`` or ``DEFAULT_FASTDDS_PROFILES.xml`` in the
working directory (Fast DDS loads those too), and the RMW is rmw_fastrtps. ``ROS_DISCOVERY_SERVER``
does not keep it out: the profile sets no discovery protocol and no server, so Fast DDS still makes
the participant that variable's client (tests/ros/test_discovery_server.py). A user's profile is never
replaced or merged: with one, discovery is as that profile says (``install`` logs that the agent's
settings stay out).
Other RMWs (Cyclone DDS, Zenoh) are left alone too; their discovery is their own.
"""

from __future__ import annotations

import logging
import os
from typing import MutableMapping, Optional

_HERE = os.path.dirname(os.path.abspath(__file__))
# Fast DDS major version -> (the agent's profile for it, the variable that version reads).
PROFILES = {
    2: (os.path.join(_HERE, "fastdds_profile.xml"), "FASTRTPS_DEFAULT_PROFILES_FILE"),
    3: (os.path.join(_HERE, "fastdds3_profile.xml"), "FASTDDS_DEFAULT_PROFILES_FILE"),
}
PROFILE_PATH, PROFILES_VARIABLE = PROFILES[2]
# Any of these set means the user configures Fast DDS (FASTDDS_ is Fast DDS 3's name).
_USER_VARIABLES = ("FASTRTPS_DEFAULT_PROFILES_FILE", "FASTDDS_DEFAULT_PROFILES_FILE")
_WORKING_DIRECTORY_FILES = ("DEFAULT_FASTRTPS_PROFILES.xml", "DEFAULT_FASTDDS_PROFILES.xml")


def user_profile_reason(environ: MutableMapping[str, str], cwd: str) -> Optional[str]:
    """Why the agent's profile must stay out (a user's Fast DDS configuration or another RMW),
    or None when it may go in."""
    rmw = environ.get("RMW_IMPLEMENTATION", "")
    if rmw and not rmw.startswith("rmw_fastrtps"):
        return "RMW_IMPLEMENTATION is %s" % rmw
    for name in _USER_VARIABLES:
        if name in environ:
            return "%s is set" % name
    for name in _WORKING_DIRECTORY_FILES:
        if os.path.exists(os.path.join(cwd, name)):
            return "%s is in the working directory" % name
    return None


def profile_for(fastdds_major: int):
    """``(path, variable)`` of the agent's profile for that Fast DDS major version (the newest
    file for versions after 3: Fast DDS 3's elements are the ones a later version keeps)."""
    return PROFILES[min(max(fastdds_major, 2), 3)]


def install(environ: Optional[MutableMapping[str, str]] = None,
            cwd: Optional[str] = None, fastdds_major: Optional[int] = None) -> Optional[str]:
    """Point Fast DDS at the agent's profile unless the user has their own; the profile's path
    when installed, else None. Must run before the first ROS participant is created;
    ``fastdds_major`` defaults to the Fast DDS the RMW loaded (env.fastdds_major)."""
    environ = os.environ if environ is None else environ
    reason = user_profile_reason(environ, os.getcwd() if cwd is None else cwd)
    if reason is not None:
        logging.getLogger("xrce.agent.rosenv").info(
            "%s: the agent's Fast DDS profile stays out (its 0.5 s announcements and asynchronous "
            "discovery writers included, docs/PERFORMANCE.md)", reason)
        return None
    if fastdds_major is None:
        from xrce.agent.interfaces import ros_install as rosenv

        fastdds_major = rosenv.fastdds_major()
    path, variable = profile_for(fastdds_major)
    environ[variable] = path
    return path
