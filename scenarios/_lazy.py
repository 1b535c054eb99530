"""Public names of a subpackage, imported from their module on first use (PEP 562).

A package's ``__init__`` lists its public functions and classes in ``__all__`` and imports them
under ``if TYPE_CHECKING:`` (for readers, type checkers and pyflakes, which then checks that the
two lists agree), without importing at run time the modules that define them: importing one light
module of the package (``scenarios.flightlog.jpeg`` in a replay's vision worker,
``scenarios.config.tuning``) does not compile numba kernels or import OpenCV for the others. The
module-level ``__getattr__`` made by :func:`lazy_exports` reads those imports and imports a name's
module when the name is first asked for.
"""
from __future__ import annotations

import ast
from functools import lru_cache
from importlib import import_module
from typing import Any, Callable


@lru_cache(maxsize=None)
def _homes(init_file: str) -> dict[str, str]:
    """{public name: submodule} from the ``from .module import name`` lines under the module-level
    ``if TYPE_CHECKING:`` of a package's ``__init__``."""
    with open(init_file, encoding="utf-8") as f:
        tree = ast.parse(f.read(), init_file)
    homes = {}
    for node in tree.body:
        if isinstance(node, ast.If) and isinstance(node.test, ast.Name) and node.test.id == "TYPE_CHECKING":
            for imp in node.body:
                if isinstance(imp, ast.ImportFrom) and imp.level == 1:
                    for alias in imp.names:
                        homes[alias.asname or alias.name] = imp.module
    return homes


def lazy_exports(package: str, init_file: str) -> Callable[[str], Any]:
    """The module-level ``__getattr__`` of ``package`` (whose ``__init__`` is ``init_file``):
    ``package.name`` imports the submodule that the ``TYPE_CHECKING`` block imports ``name`` from
    and returns its attribute. Any other name raises AttributeError, so submodules import as usual."""
    def __getattr__(name: str) -> Any:
        module = _homes(init_file).get(name)
        if module is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        return getattr(import_module(f"{package}.{module}"), name)

    return __getattr__
