"""The module paths of jaxmpm before its layers (jaxmpm.moved): importable for one release, each use
warning with the new path, and the same objects as at the new path."""

import importlib

import pytest

import jaxmpm
import jaxmpm.run.planning
from jaxmpm.moved import MOVED


@pytest.mark.parametrize("old", sorted(MOVED))
def test_old_path_warns_and_gives_the_new_modules_objects(old):
    new = importlib.import_module(MOVED[old])
    name = next(
        n for n in vars(new) if not n.startswith("_") and getattr(getattr(new, n), "__module__", None) == new.__name__
    )
    module = importlib.import_module(old)
    with pytest.warns(DeprecationWarning, match=f"{old} moved to {MOVED[old]}"):
        value = getattr(module, name)
    assert value is getattr(new, name)


def test_from_import_of_an_old_path_and_the_attribute_of_the_package():
    with pytest.warns(DeprecationWarning, match="jaxmpm.state moved to jaxmpm.model.state"):
        from jaxmpm.state import State
    assert State is jaxmpm.State
    importlib.import_module("jaxmpm.planning")
    with pytest.warns(DeprecationWarning, match="jaxmpm.planning moved to jaxmpm.run.planning"):
        assert jaxmpm.planning.plan_steps is jaxmpm.plan_steps


def test_setting_through_an_old_path_is_refused_with_the_new_path(monkeypatch):
    old = importlib.import_module("jaxmpm.planning")
    with (
        pytest.warns(DeprecationWarning),
        pytest.raises(AttributeError, match="jaxmpm.planning moved to jaxmpm.run.planning: set max_minutes on"),
    ):
        monkeypatch.setattr(old, "max_minutes", None)
    assert callable(jaxmpm.run.planning.max_minutes)


def test_public_names_are_not_replaced_by_old_module_paths():
    importlib.import_module("jaxmpm.simulate")
    assert callable(jaxmpm.simulate) and jaxmpm.simulate.__module__ == "jaxmpm.run.simulate"
    with pytest.raises(AttributeError, match="no attribute 'no_such_module'"):
        _ = jaxmpm.no_such_module
