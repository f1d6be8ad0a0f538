"""xrce.agent.middleware.ros.deferred: a deferred module runs on first use of a name, never on import alone."""

import importlib
import sys

import pytest

from xrce.agent.middleware.ros import deferred


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


def test_from_import_of_a_prepared_name_does_not_run_it(probe_module):
    """``from m import name`` asks a plain module for ``__path__`` first: that must not run it."""
    name = probe_module
    assert deferred.defer(name, lambda module: setattr(module, "early", 42))
    namespace = {}
    exec("from %s import early" % name, namespace)
    assert namespace["early"] == 42 and "%s_runs" % name not in sys.modules


def test_a_stand_in_runs_the_module_when_called(probe_module):
    name = probe_module
    assert deferred.defer(name, lambda module: setattr(
        module, "hello", deferred.on_first_call(module, "hello")))
    namespace = {}
    exec("from %s import hello" % name, namespace)  # what a library's import line does
    assert "%s_runs" % name not in sys.modules
    assert namespace["hello"]() == "hello"  # the stand-in, kept by the importer
    assert sys.modules["%s_runs" % name] == 1
    assert sys.modules[name].hello() == "hello"  # the module's own function from now on
    assert sys.modules[name].hello is not namespace["hello"]
    assert namespace["hello"]() == "hello" and sys.modules["%s_runs" % name] == 1


def test_a_deferred_submodule_is_bound_in_its_package(request, tmp_path, monkeypatch):
    package = "xrce_deferred_pkg_" + request.node.name
    (tmp_path / package).mkdir()
    (tmp_path / package / "__init__.py").write_text("")
    (tmp_path / package / "sub.py").write_text("value = 7\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    importlib.invalidate_caches()
    try:
        assert deferred.defer(package + ".sub")
        namespace = {}
        exec("import %s.sub\nvalue = %s.sub.value" % (package, package), namespace)
        assert namespace["value"] == 7
    finally:
        for name in (package + ".sub", package):
            sys.modules.pop(name, None)
