"""Modules registered before their code runs: it runs on first use of a name they define.

The agent process imports some modules only because a library imports them at start-up for a
feature the agent never uses (rclpy imports ``yaml`` for parameter files; every generated message
class imports ``rosidl_generator_py``, whose ``__init__`` loads the code generator). ``defer``
puts the module in ``sys.modules`` without executing it; the first access to a name it does not
have executes it, whole, so nothing is lost, and until then it costs no memory.

``importlib.util.LazyLoader`` does the same, but on CPython 3.11 the ``import`` statement itself
reads the module's ``__spec__`` and so loads it at once; a module-level ``__getattr__`` is only
consulted for names the module lacks (``__path__`` aside: ``from m import x`` asks every module
for it, and a plain module answers that it has none without running). A class or function that
a library imports by name but rarely calls can be given as ``on_first_call`` stand-in.
"""

from __future__ import annotations

import importlib.util
import sys
import threading
from typing import Callable, Optional


def defer(name: str, prepare: Optional[Callable[[object], None]] = None) -> bool:
    """Register module ``name`` unexecuted; ``prepare(module)`` may give it names that must not
    trigger its execution. False (nothing done) when it is imported already or cannot be found,
    or when ``prepare`` raises (then the module imports the usual way)."""
    if name in sys.modules:
        return False
    spec = importlib.util.find_spec(name)
    if spec is None or spec.loader is None:
        return False
    module = importlib.util.module_from_spec(spec)
    lock = threading.Lock()
    executed = []

    def run():
        with lock:
            if not executed:
                executed.append(True)
                del module.__getattr__  # the module's own names from now on
                spec.loader.exec_module(module)

    def __getattr__(attribute):
        if attribute == "__path__":  # asked of every module by "from m import x": not a package
            raise AttributeError(attribute)
        run()
        try:
            return module.__dict__[attribute]
        except KeyError:
            raise AttributeError("module %r has no attribute %r" % (name, attribute)) from None

    parent, _, child = name.rpartition(".")
    sys.modules[name] = module
    _RUNS[name] = run
    try:
        if prepare is not None:
            prepare(module)
    except Exception:
        del sys.modules[name]
        del _RUNS[name]
        return False
    module.__getattr__ = __getattr__
    if parent:  # as an import binds a submodule: "import a.b" then reads a.b
        setattr(sys.modules[parent], child, module)
    return True


_RUNS = {}  # deferred module name -> runs its code (once)


def on_first_call(module, name: str) -> Callable:
    """A stand-in for the callable ``name`` of the deferred ``module``, for ``prepare``: calling
    it runs the module, then calls the module's own ``name`` (which replaced the stand-in in the
    module; a ``from module import name`` done earlier keeps the stand-in, which stays right)."""
    run = _RUNS[module.__name__]

    def call(*args, **kwargs):
        run()
        return getattr(module, name)(*args, **kwargs)

    call.__name__ = call.__qualname__ = name
    return call
