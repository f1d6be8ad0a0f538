"""The Fast DDS profile ``xrce-agent`` uses when the user has none (``fastdds_profile.xml``).

Fast DDS preallocates its send buffers when the participant is created: three plus one per
receive thread, each of the largest message size (64 KB) and zero-filled, so all of them are
resident memory (640 KB of the agent's ~51 MB under the TurtleBot3 load) although a process sends
from only a few threads. The profile asks for one and lets Fast DDS add one when a thread finds
none free (``SendBuffersAllocationAttributes``: preallocated_number 1, dynamic). Nothing else
changes: discovery, transports, QoS and ports stay as rmw_fastrtps and Fast DDS make them.

It goes in through ``FASTRTPS_DEFAULT_PROFILES_FILE`` (the variable Fast DDS 2.x, ROS 2 Jazzy's,
reads) and only when nothing says the user configures Fast DDS themselves: no profiles file in
either variable, no ``DEFAULT_FASTRTPS_PROFILES.xml`` in the working directory (Fast DDS loads
that one too), and the RMW is rmw_fastrtps. A user's profile is never replaced or merged.
"""

from __future__ import annotations

import os
from typing import MutableMapping, Optional

PROFILE_PATH = os.path.join(os.path.dirname(os.path.abspath(__file__)), "fastdds_profile.xml")
PROFILES_VARIABLE = "FASTRTPS_DEFAULT_PROFILES_FILE"
# Any of these set means the user configures Fast DDS (FASTDDS_ is Fast DDS 3's name).
_USER_VARIABLES = (PROFILES_VARIABLE, "FASTDDS_DEFAULT_PROFILES_FILE")
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


def install(environ: Optional[MutableMapping[str, str]] = None,
            cwd: Optional[str] = None) -> Optional[str]:
    """Point Fast DDS at the agent's profile unless the user has their own; the profile's path
    when installed, else None. Must run before the first ROS participant is created."""
    environ = os.environ if environ is None else environ
    if user_profile_reason(environ, os.getcwd() if cwd is None else cwd) is not None:
        return None
    environ[PROFILES_VARIABLE] = PROFILE_PATH
    return PROFILE_PATH
