"""The flat layout's module paths (0.x) still import, for one release: the module at its new home,
the same object, with one DeprecationWarning naming both paths."""

from __future__ import annotations

import importlib
import sys

import pytest

import apf_physics  # noqa: F401 (installs the old paths)


@pytest.mark.parametrize(("old", "new"), [
    ("apf_physics.evaluate", "apf_physics.experiments.evaluate"),
    ("apf_physics.actions", "apf_physics.control.shield"),
    ("apf_physics.worldschema", "apf_physics.world.io.schema"),
    ("apf_physics.rl", "apf_physics.learning"),
    ("apf_physics.rl.config", "apf_physics.learning.config"),          # a moved package's modules move with it
    ("apf_physics.rl.evaluation", "apf_physics.learning.validation"),  # the longest moved prefix wins
    ("apf_physics.envs.formations", "apf_physics.envs.parallel"),
])
def test_an_old_path_imports_the_module_at_its_new_home_with_a_warning(old, new, monkeypatch):
    for name in [n for n in sys.modules if n == old or n.startswith(old + ".")]:
        monkeypatch.delitem(sys.modules, name)          # imported afresh, as by a user's first import
    parent = old.rpartition(".")[0]
    if parent != "apf_physics":
        importlib.import_module(parent)
    with pytest.warns(DeprecationWarning, match=rf"^{old} moved to {new}; the old path goes in the next release$"):
        module = importlib.import_module(old)
    assert module is importlib.import_module(new)
    assert module.__name__ == new and module.__spec__.name == new


def test_paths_that_did_not_move_import_without_a_warning_or_fail_as_before(recwarn):
    module = importlib.import_module("apf_physics.world.field")
    assert module.__name__ == "apf_physics.world.field"
    assert not [w for w in recwarn if issubclass(w.category, DeprecationWarning)]
    with pytest.raises(ModuleNotFoundError, match="apf_physics.no_such_module"):
        importlib.import_module("apf_physics.no_such_module")
