"""The agent's modules import cleanly and none is shadowed by a name its package offers.

Each check that imports runs in a fresh interpreter: this process has imported the agent's modules
already, and a warning is only seen where a module is imported for the first time."""

import pkgutil
import subprocess
import sys

import xrce.agent
from agent_process import REPO


def _run(script):
    done = subprocess.run([sys.executable, "-c", script], cwd=REPO, capture_output=True, text=True,
                          timeout=120)
    assert done.returncode == 0, done.stderr[-3000:]
    return done.stdout


def test_the_agent_itself_imports_nothing_deprecated():
    """Every module of the agent imports with DeprecationWarning an error: none of them, nor the
    modules they import, uses a deprecated name."""
    names = [m.name for m in pkgutil.walk_packages(xrce.agent.__path__, "xrce.agent.")
             if not m.name.endswith(".__main__")]  # __main__ runs
    assert "xrce.agent.middleware.ros.ros_middleware" in names and \
        "xrce.agent.observe.capture" in names
    script = ("import importlib, warnings\nwarnings.simplefilter('error', DeprecationWarning)\n"
              "for name in %r:\n    importlib.import_module(name)\nprint('imported')\n" % names)
    assert _run(script).strip() == "imported"


def test_the_module_names_of_before_the_subpackages_are_gone():
    """The aliases of the layout before the subpackages (issue 24) are gone with the module that
    kept them (issue 46): an old name is not found."""
    out = _run("import importlib\n"
               "for old in ('xrce.agent.session', 'xrce.agent.ros', 'xrce.agent._fastpath',\n"
               "            'xrce.agent._moved'):\n"
               "    try:\n        importlib.import_module(old)\n"
               "    except ModuleNotFoundError as exc:\n        print(exc.name)\n"
               "from xrce.agent import engine\nprint(hasattr(engine, 'Agent'))\n")
    assert out.split() == ["xrce.agent.session", "xrce.agent.ros", "xrce.agent._fastpath",
                           "xrce.agent._moved", "False"]


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
        submodules = {m.name for m in pkgutil.iter_modules(module.__path__)}
        assert not offered & submodules, package
