"""Where the agent's resident memory goes under the TurtleBot3 load: /proc/<pid>/smaps by kind.

    .venv/bin/python bench/agent/memory.py [--tree DIR] [--agent-cmd CMD] [--libraries N]

The agent (this tree's, ``--tree DIR``'s, or ``--agent-cmd CMD``'s, e.g. eProsima's
``$PEERS/agent.sh``) runs the TurtleBot3 load of bench/agent/cost.py (simulated robot, odom/imu
subscriber, reliable cmd_vel at 30 Hz from ROS); at the point where that script reads VmRSS, the
mappings' ``Rss`` are summed by what they are:

- anonymous memory apart from thread stacks and thread malloc arenas: CPython's object arenas
  (1 MB each, the Python objects and the code of every imported module) and what C++ code maps
  by itself; the C heap (``[heap]``, glibc's main arena: Fast DDS's and rcl's allocations, Python's
  objects over 512 bytes); thread malloc arenas (64 MB-aligned reservations); thread stacks;
- each group of libraries: Fast DDS, the type supports (``*__rosidl_*``; those that rclpy's
  extension links by name, directly or through its NEEDED libraries, are counted apart: any
  rclpy process maps them), libpython, libc/libstdc++/libm/libgcc/ld.so, rclpy's extension, the
  rest; Fast DDS's shared-memory transport segments (/dev/shm).

Run it inside ``unshare -nm sh -c 'ip link set lo up && mount -t tmpfs tmpfs /dev/shm && ...'``
(docs/PERFORMANCE.md) so that no other DDS participant of the machine joins in. One run: RSS
varies by ~0.3 MB between runs; compare kinds, not tenths.
"""

import argparse
import collections
import glob
import os
import re
import subprocess
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the checkout: bench.common, xrce
from bench.common import REPO  # noqa: E402  (and the test helpers on sys.path)

from bench.agent import cost as agent_cost  # noqa: E402

HEAP_MAX = 64 << 20  # glibc's thread arena reservation (64-bit)

LIBRARY_GROUPS = (
    ("Fast DDS (libfastrtps/libfastdds, libfastcdr)", re.compile(r"/libfast(rtps|dds|cdr)\.so")),
    ("libpython", re.compile(r"/libpython3")),
    ("libc, libstdc++, libm, libgcc, ld.so",
     re.compile(r"/(libc|libstdc\+\+|libm|libgcc_s|ld-linux[^/]*)\.so")),
    ("rclpy's extension", re.compile(r"/rclpy/_rclpy_pybind11")),
    ("Fast DDS shared-memory segments", re.compile(r"^/dev/shm/")),
)


def rclpy_linked_type_supports():
    """Base names of the type support libraries rclpy's extension loads with itself (ldd: its
    NEEDED ones and theirs)."""
    try:
        import rclpy
    except ImportError:
        return set()
    names = set()
    folder = os.path.dirname(rclpy.__file__)
    for extension in glob.glob(os.path.join(folder, "_rclpy_pybind11*.so")):
        listing = subprocess.run(["ldd", extension], capture_output=True, text=True).stdout
        names.update(line.split()[0] for line in listing.splitlines() if "__rosidl_" in line)
    return names


def smaps_groups(pid, rclpy_linked):
    """{kind: kB resident}, {type support package: kB}, {other file: kB}."""
    mappings = []
    with open("/proc/%d/smaps" % pid) as smaps:
        for line in smaps:
            if re.match(r"^[0-9a-f]+-[0-9a-f]+ ", line):
                fields = line.split()
                low, high = (int(x, 16) for x in fields[0].split("-"))
                mappings.append([low, high, fields[1], fields[5] if len(fields) > 5 else "", 0])
            elif line.startswith("Rss:"):
                mappings[-1][4] = int(line.split()[1])
    ends = {high for _low, high, _perm, _name, _rss in mappings}
    groups, packages, others = collections.Counter(), collections.Counter(), collections.Counter()
    for index, (low, high, perm, name, rss) in enumerate(mappings):
        if not rss:
            continue
        if name == "[heap]":
            kind = "C heap ([heap], glibc's main arena)"
        elif name == "":
            previous = mappings[index - 1] if index else None
            if low % HEAP_MAX == 0 and (high - low == HEAP_MAX or low + HEAP_MAX in ends):
                kind = "thread malloc arenas"
            elif (previous and previous[2] == "---p" and previous[1] == low
                  and high - low >= (1 << 20) and previous[1] - previous[0] <= 64 << 10):
                kind = "thread stacks"
            else:
                kind = "anonymous (Python's object arenas, C++ mappings)"
        elif "__rosidl_" in name:
            base = os.path.basename(name)
            kind = ("type supports rclpy links" if base in rclpy_linked
                    else "type supports of the bridged types")
            packages[base.split("__rosidl_")[0][3:]] += rss
        else:
            kind = next((label for label, pattern in LIBRARY_GROUPS if pattern.search(name)), None)
            if kind is None:
                kind = "other libraries and files (rcl, rmw, spdlog, lttng, yaml, extensions)"
                others[os.path.basename(name)] += rss
        groups[kind] += rss
    return groups, packages, others


def main(argv=None):
    from ros_helpers import DomainLease

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tree", metavar="DIR", help="the agent of this source tree")
    parser.add_argument("--agent-cmd", metavar="CMD", help="another agent's command line")
    parser.add_argument("--libraries", type=int, default=0, metavar="N",
                        help="also list the N largest other mappings")
    args = parser.parse_args(argv)
    rclpy_linked = rclpy_linked_type_supports()
    captured = {}
    read_rss = agent_cost.rss_mb

    def rss_and_smaps(pid):
        captured["rss"] = read_rss(pid)
        groups, packages, others = smaps_groups(pid, rclpy_linked)
        captured.update(groups=groups, packages=packages, others=others)
        return captured["rss"]

    agent_cost.rss_mb = rss_and_smaps
    lease = DomainLease()
    env = dict(os.environ, ROS_DOMAIN_ID=str(lease.domain_id),
               ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    try:
        agent = (agent_cost.OtherAgent(args.agent_cmd, env) if args.agent_cmd
                 else agent_cost.Agent(args.tree or str(REPO), env))
        try:
            agent_cost.robot_load(agent, env, lease.domain_id, agent_cost.IDLE_SECONDS)
            threads = len(os.listdir("/proc/%d/task" % agent.pid))
        finally:
            agent.stop()
    finally:
        lease.release()
    groups = captured["groups"]
    print("agent RSS under the TurtleBot3 load: %.1f MB (VmRSS), %d threads; smaps by kind:"
          % (captured["rss"], threads))
    for kind, kb in groups.most_common():
        print("  %6.2f MB  %s" % (kb / 1024.0, kind))
    print("  %6.2f MB  total of the above" % (sum(groups.values()) / 1024.0))
    if captured["packages"]:
        print("type supports by package (all their libraries):")
        for package, kb in captured["packages"].most_common():
            print("  %6.2f MB  %s" % (kb / 1024.0, package))
    if args.libraries:
        print("the %d largest other libraries and files:" % args.libraries)
        for name, kb in captured["others"].most_common(args.libraries):
            print("  %6.2f MB  %s" % (kb / 1024.0, name))
    return 0


if __name__ == "__main__":
    sys.exit(main())
