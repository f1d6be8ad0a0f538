"""Dependencies are decided here, when pip builds xrce, because they depend on where rclpy comes from.

With a ROS 2 sourced in the installing shell (ROS_DISTRO set) xrce runs on that ROS and must not pull
a second one from PyPI; otherwise the ros-jazzy-* wheels from PyPI are a dependency (on the platforms
PyPI has them for). XRCE_ROS=pypi|system overrides the guess; XRCE_ROS_DISTRO=kilted takes the
ros-kilted-* wheels (Fast DDS 3) instead of Jazzy's. The rules live in
xrce/agent/middleware/ros/env.py, loaded by path: the package itself is not importable in pip's
build environment.

The agent's compiled UDP receive path (xrce/agent/engine/_fastpath.c, see
xrce/agent/engine/fastpath.py) is an optional extension: without a C compiler pip still installs
xrce and the agent runs pure Python. XRCE_FASTPATH=0 at build time leaves it out (a pure,
platform-independent wheel).
"""

import binascii
import importlib.util
import os

from setuptools import Extension, setup

_spec = importlib.util.spec_from_file_location(
    "_xrce_rosenv", os.path.join(os.path.dirname(os.path.abspath(__file__)),
                                 "xrce", "agent", "middleware", "ros", "env.py"))
_rosenv = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(_rosenv)

try:
    _install_requires, _extras_require = _rosenv.install_requirements()
except ValueError as exc:
    raise SystemExit("xrce: %s" % exc) from None

_extensions = []
if os.environ.get("XRCE_FASTPATH", "1").strip().lower() not in ("0", "no", "off", "false"):
    # The sources' CRC goes into the module: fastpath.attach() leaves a module built from another
    # version of them unused (an editable install's .so outlives edits to the .c). Every .c and .h
    # of the engine's folder, by name: the same list fastpath.stale_build reads.
    _engine = os.path.join(os.path.dirname(os.path.abspath(__file__)), "xrce", "agent", "engine")
    _names = sorted(n for n in os.listdir(_engine) if n.endswith((".c", ".h")))
    _source_crc = 0
    for _name in _names:
        with open(os.path.join(_engine, _name), "rb") as _source:
            _source_crc = binascii.crc32(_source.read(), _source_crc)
    _source_crc = "%08x" % _source_crc
    _extensions.append(Extension("xrce.agent.engine._fastpath",
                                 ["xrce/agent/engine/" + n for n in _names if n.endswith(".c")],
                                 depends=["xrce/agent/engine/" + n for n in _names if n.endswith(".h")],
                                 define_macros=[("XRCE_FASTPATH_SOURCE_CRC", '"%s"' % _source_crc)],
                                 extra_compile_args=["-O2"], optional=True))

setup(install_requires=_install_requires, extras_require=_extras_require, ext_modules=_extensions)
