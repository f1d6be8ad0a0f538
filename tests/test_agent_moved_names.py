"""The agent's module names from before its subpackages (issue 24) still import, for one release:
the same module objects, one DeprecationWarning each naming the new module (xrce/agent/_moved.py).

Each check runs in a fresh interpreter: this process has imported the agent's modules already,
and a warning is only worth checking where the old name is imported for the first time."""

import json
import pkgutil
import subprocess
import sys

import xrce.agent
from agent_process import REPO
from xrce.agent import _moved

_OLD_NAMES_SCRIPT = r"""
import importlib, json, sys, warnings
from xrce.agent import _moved

results = {}
for old, new in sorted(_moved.MOVED.items()):
    if importlib.util.find_spec(new) is None:
        results[old] = "not built"  # only the optional extension may be missing
        continue
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        parent, _, leaf = old.rpartition(".")
        exec("import %s as first\nimport %s as again\nfrom %s import %s as imported"
             % (old, old, parent, leaf), namespace := {})  # once imported, cached: no warning
    first = namespace["first"]
    results[old] = {
        "same": first is namespace["again"] is namespace["imported"] is sys.modules[new],
        "name": first.__name__,
        "warnings": [(str(w.message), w.category.__name__, w.filename) for w in caught],
    }
print(json.dumps(results))
"""


def _run(script):
    done = subprocess.run([sys.executable, "-c", script], cwd=REPO, capture_output=True, text=True,
                          timeout=120)
    assert done.returncode == 0, done.stderr[-3000:]
    return done.stdout


def test_every_old_module_name_imports_the_moved_module_and_warns_once():
    results = json.loads(_run(_OLD_NAMES_SCRIPT))
    assert set(results) == set(_moved.MOVED)
    for old, result in results.items():
        new = _moved.MOVED[old]
        if result == "not built":
            assert new == "xrce.agent.engine._fastpath", old
            continue
        assert result["same"] and result["name"] == new, (old, result)
        # One warning, naming the new module, attributed to the line that imported the old name.
        assert result["warnings"] == [
            ["%s is now %s; the old name goes with the next release" % (old, new),
             "DeprecationWarning", "<string>"]], (old, result)


def test_old_engine_names_read_from_the_engine_package():
    script = r"""
import warnings
from xrce.agent.engine import dispatch, session
with warnings.catch_warnings(record=True) as caught:
    warnings.simplefilter("always")
    from xrce.agent.engine import fastpath, Agent, CLIENT_DEAD_TIME
assert Agent is dispatch.Agent and CLIENT_DEAD_TIME == session.CLIENT_DEAD_TIME
print(sorted(str(w.message) for w in caught))
try:
    from xrce.agent.engine import NoSuchName
except ImportError as exc:
    print("ImportError", exc.name)
"""
    lines = _run(script).splitlines()
    assert lines[0] == str(sorted([
        "xrce.agent.engine.Agent is now xrce.agent.engine.dispatch.Agent; "
        "the old name goes with the next release",
        "xrce.agent.engine.CLIENT_DEAD_TIME is now xrce.agent.engine.dispatch.CLIENT_DEAD_TIME; "
        "the old name goes with the next release"]))  # and none for the submodule fastpath
    assert lines[1] == "ImportError xrce.agent.engine"


def test_a_name_that_never_existed_is_still_not_found():
    out = _run("try:\n import xrce.agent.no_such_module\n"
               "except ModuleNotFoundError as exc:\n print(exc.name)\n")
    assert out.strip() == "xrce.agent.no_such_module"


def test_the_agent_itself_imports_no_old_name():
    """Every module of the agent imports with DeprecationWarning an error: none of them, nor the
    modules they import, uses an old name."""
    names = [m.name for m in pkgutil.walk_packages(xrce.agent.__path__, "xrce.agent.")
             if not m.name.endswith(".__main__") and m.name != "xrce.agent._moved"]  # __main__ runs
    assert "xrce.agent.middleware.ros.entities" in names and "xrce.agent.observe.capture" in names
    script = ("import importlib, warnings\nwarnings.simplefilter('error', DeprecationWarning)\n"
              "for name in %r:\n    importlib.import_module(name)\nprint('imported')\n" % names)
    assert _run(script).strip() == "imported"


def test_no_submodule_shares_a_name_with_what_its_package_offers():
    """A package's name that is also one of its submodules is replaced by the submodule once that
    is imported (``xrce.agent.interfaces.build``, the function, against a module ``build``)."""
    import importlib
    import types

    for package in [m.name for m in pkgutil.walk_packages(xrce.agent.__path__, "xrce.agent.")
                    if m.ispkg] + ["xrce.agent"]:
        module = importlib.import_module(package)
        offered = {name for name, value in vars(module).items()
                   if not isinstance(value, types.ModuleType)}
        offered |= set(getattr(module, "_FROM_BUILD", ()))  # read through a module __getattr__
        if package == "xrce.agent.engine":
            offered |= _moved.OLD_ENGINE_NAMES
        submodules = {m.name for m in pkgutil.iter_modules(module.__path__)}
        assert not offered & submodules, package
