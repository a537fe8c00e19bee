"""Lazy package exports: a package names what it offers, and each name's submodule is imported on first use.

:func:`lazy_exports` builds the module-level ``__getattr__`` and ``__dir__`` (PEP 562) of a package whose
``__init__`` must stay light (no torch, numba or open3d at import): ``import fusion.train`` costs nothing, and
``fusion.train.train_splats`` imports :mod:`fusion.train.trainer` the first time it is read. The value is then
stored in the package's namespace, so later reads are ordinary attribute lookups.

Usage, in a package's ``__init__.py``::

    __getattr__, __dir__ = lazy_exports(__name__, {"train_splats": "trainer", "TrainOptions": "options"})
"""

from __future__ import annotations

import importlib
import sys
from collections.abc import Callable, Mapping
from typing import Any


def lazy_exports(module_name: str, exports: Mapping[str, str]) -> tuple[Callable[[str], Any], Callable[[], list[str]]]:
    """(``__getattr__``, ``__dir__``) for the package ``module_name``.

    exports: exported name → the submodule (relative to ``module_name``) that defines it. ``__getattr__(name)``
    imports ``module_name.submodule``, stores the value under ``name`` in the package's namespace and returns it;
    other names raise :class:`AttributeError` as a module without them would. ``__dir__()`` lists the package's
    namespace and every exported name, sorted.
    """
    table = dict(exports)

    def __getattr__(name: str) -> Any:
        if name in table:
            value = getattr(importlib.import_module(f"{module_name}.{table[name]}"), name)
            vars(sys.modules[module_name])[name] = value
            return value
        raise AttributeError(f"module {module_name!r} has no attribute {name!r}")

    def __dir__() -> list[str]:
        return sorted(set(vars(sys.modules[module_name])) | set(table))

    return __getattr__, __dir__
