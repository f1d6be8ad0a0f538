"""Dependencies are decided here, when pip builds xrce, because they depend on where rclpy comes from.

With a ROS 2 sourced in the installing shell (ROS_DISTRO set) xrce runs on that ROS and must not pull
a second one from PyPI; otherwise the ros-jazzy-* wheels from PyPI are a dependency (on the platforms
PyPI has them for). XRCE_ROS=pypi|system overrides the guess; XRCE_ROS_DISTRO=kilted takes the
ros-kilted-* wheels (Fast DDS 3) instead of Jazzy's. The rules live in
xrce/agent/interfaces/ros_install.py, loaded by path: the package itself is not importable in pip's
build environment.

Three optional C extensions, each built from every .c and .h of its folder; without a C compiler
pip still installs xrce and the agent runs pure Python, each missing one costing only speed or a
feature:
- ``xrce.agent.engine.compiled._fastpath`` (xrce/agent/engine/compiled/, see fastpath.py there):
  the UDP link's compiled receive path. Without it every datagram goes through Python (the
  agent's cost per message, bench/agent_cost.py).
- ``xrce.agent.middleware.ros._rostypes`` (xrce/agent/middleware/ros/, see compiled.py there):
  the ROS type supports. Without it the packages' generated Python classes carry samples and
  service calls (slower entity creation, more memory, two conversions per request), a type
  known only by its DDS name (PX4's px4_msgs without the package) is refused, and a domain's DDS
  participant is made with the GIL held.
- ``xrce.agent._heap`` (xrce/agent/_heap.c, see heap.py there): malloc_trim for the engine and
  the middleware. Without it that goes through ctypes, which stays loaded (0.57 MB).
XRCE_FASTPATH=0 at build time leaves all three out: a pure, platform-independent wheel.
"""

import importlib.util
import os

from setuptools import Extension, setup

_HERE = os.path.dirname(os.path.abspath(__file__))


def _load_by_path(name, *path):
    spec = importlib.util.spec_from_file_location(name, os.path.join(_HERE, *path))
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


_rosenv = _load_by_path("_xrce_rosenv", "xrce", "agent", "interfaces", "ros_install.py")
_c_sources = _load_by_path("_xrce_c_sources", "xrce", "agent", "c_sources.py")

try:
    _install_requires, _extras_require = _rosenv.install_requirements()
except ValueError as exc:
    raise SystemExit("xrce: %s" % exc) from None


def _extension(name, folder):
    """The extension ``name`` built from ``folder``'s C sources, their CRC baked in (SOURCE_CRC):
    the agent leaves a module built from another version of them unused (an editable install's
    .so outlives edits to the .c; xrce/agent/c_sources.py, which computes it for both sides)."""
    names = _c_sources.source_names(os.path.join(_HERE, folder))
    return Extension(name, [folder + "/" + n for n in names if n.endswith(".c")],
                     depends=[folder + "/" + n for n in names if n.endswith(".h")],
                     define_macros=[("XRCE_SOURCE_CRC",
                                     '"%s"' % _c_sources.source_crc(os.path.join(_HERE, folder)))],
                     extra_compile_args=["-O2"], optional=True)


_extensions = []
if os.environ.get("XRCE_FASTPATH", "1").strip().lower() not in ("0", "no", "off", "false"):
    _extensions.append(_extension("xrce.agent.engine.compiled._fastpath", "xrce/agent/engine/compiled"))
    _extensions.append(_extension("xrce.agent._heap", "xrce/agent"))
    _extensions.append(_extension("xrce.agent.middleware.ros._rostypes", "xrce/agent/middleware/ros"))

setup(install_requires=_install_requires, extras_require=_extras_require, ext_modules=_extensions)
