"""xrce.agent.deferred: a deferred module runs on first use of a name, never on import alone."""

import importlib
import sys

import pytest

from xrce.agent import deferred


@pytest.fixture
def probe_module(request, tmp_path, monkeypatch):
    """The name of a fresh module on sys.path that counts its runs in sys.modules[name + '_runs']."""
    name = "xrce_deferred_" + request.node.name
    (tmp_path / ("%s.py" % name)).write_text(
        "import sys\n"
        "sys.modules['%s_runs'] = sys.modules.get('%s_runs', 0) + 1\n"
        "def hello():\n    return 'hello'\n" % (name, name))
    monkeypatch.syspath_prepend(str(tmp_path))
    importlib.invalidate_caches()
    yield name
    sys.modules.pop(name, None)
    sys.modules.pop("%s_runs" % name, None)


def test_runs_on_first_use_only(probe_module):
    name = probe_module
    assert deferred.defer(name)
    module = importlib.import_module(name)  # what a library's "import name" does
    exec("import %s" % name, {})
    assert "%s_runs" % name not in sys.modules
    assert module.hello() == "hello"
    assert module.hello() == "hello"
    assert sys.modules["%s_runs" % name] == 1
    assert not deferred.defer(name)  # already there: left alone


def test_prepared_names_do_not_run_it(probe_module):
    name = probe_module
    assert deferred.defer(name, lambda module: setattr(module, "early", 42))
    module = sys.modules[name]
    assert module.early == 42 and "%s_runs" % name not in sys.modules
    with pytest.raises(AttributeError):
        module.missing  # a name the module lacks: runs it, then raises
    assert sys.modules["%s_runs" % name] == 1 and module.hello() == "hello"


def test_unknown_module_is_not_registered():
    assert not deferred.defer("xrce_no_such_module_anywhere")
    assert "xrce_no_such_module_anywhere" not in sys.modules
