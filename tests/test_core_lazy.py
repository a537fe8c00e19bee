"""core.lazy.lazy_exports: a package's names import their submodule on first access, and only then."""

from __future__ import annotations

import importlib
import sys
import textwrap
from pathlib import Path

import pytest


@pytest.fixture
def toy(tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    """A package ``lazytoy`` exporting ``Thing`` (from ``heavy``) and ``helper`` (from ``light``) lazily."""
    pkg = tmp_path / "lazytoy"
    pkg.mkdir()
    (pkg / "__init__.py").write_text(
        textwrap.dedent(
            """
            from core.lazy import lazy_exports

            __all__ = ["Thing", "helper"]
            __getattr__, __dir__ = lazy_exports(__name__, {"Thing": "heavy", "helper": "light"})
            """
        )
    )
    (pkg / "heavy.py").write_text("IMPORTS = []\nIMPORTS.append(1)\n\nclass Thing:\n    pass\n")
    (pkg / "light.py").write_text("def helper():\n    return 42\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    yield importlib.import_module("lazytoy")
    for name in [m for m in sys.modules if m == "lazytoy" or m.startswith("lazytoy.")]:
        del sys.modules[name]


def test_a_name_imports_its_submodule_only_on_first_access(toy) -> None:
    assert "lazytoy.heavy" not in sys.modules and "lazytoy.light" not in sys.modules
    assert toy.helper() == 42
    assert "lazytoy.light" in sys.modules and "lazytoy.heavy" not in sys.modules
    thing = toy.Thing
    assert thing is sys.modules["lazytoy.heavy"].Thing
    assert vars(toy)["Thing"] is thing  # cached in the package: later reads skip __getattr__
    assert toy.Thing is thing and sys.modules["lazytoy.heavy"].IMPORTS == [1]
    from lazytoy import Thing  # the from-import form takes the same path

    assert Thing is thing


def test_unknown_names_raise_attribute_error(toy) -> None:
    with pytest.raises(AttributeError, match="module 'lazytoy' has no attribute 'Missing'"):
        _ = toy.Missing
    assert not hasattr(toy, "heavy_thing")
    with pytest.raises(ImportError):
        from lazytoy import Missing  # noqa: F401


def test_dir_lists_the_exports_before_and_after_loading(toy) -> None:
    names = dir(toy)
    assert {"Thing", "helper", "__getattr__", "__dir__"} <= set(names) and names == sorted(names)
    assert "lazytoy.heavy" not in sys.modules  # dir() imports nothing
    _ = toy.Thing
    assert dir(toy).count("Thing") == 1


@pytest.mark.parametrize("package", ["fusion.render", "fusion.train"])
def test_project_packages_export_what_they_list(package: str) -> None:
    """Every name in the lazy packages' ``__all__`` is offered by ``dir`` (resolving them would import torch, which
    tests/test_cli_no_torch.py keeps out of a bare import)."""
    mod = importlib.import_module(package)
    assert set(mod.__all__) <= set(dir(mod))
    with pytest.raises(AttributeError):
        _ = mod.no_such_name
