"""The one registry mechanism: a set of choices is a package, each choice one module (or
sub-package) in it, looked up by its name.

Adding a choice is adding one file to its package. The registries: selection strategies
(``mimicgen_pipe.method.selection``), executors (``mimicgen_pipe.run.executors``), exporters
(``mimicgen_pipe.formats.exporters``), simulator back ends (``mimicgen_pipe.backends``) and each
back end's tasks (``mimicgen_pipe.tasks.<backend>``); each package's docstring states what
its modules define.

Every call site names its package as a string literal (``load("mimicgen_pipe.formats.exporters",
name)``): scripts/dvc_deps.py reads those calls to make every module of the package a code
dep of the stages that may load one.
"""

from __future__ import annotations

import importlib
import importlib.util
import sys
import types
from pathlib import Path

from mimicgen_pipe.core.errors import InputError


def _folder(package: str) -> Path:
    """The directory of the dotted package ``package``: an imported package's own
    ``__path__``, else found from its top-level package's location, importing nothing."""
    if package in sys.modules:
        locations = list(getattr(sys.modules[package], "__path__", ()))
        rest: list[str] = []
    else:
        top, *rest = package.split(".")
        spec = importlib.util.find_spec(top)
        locations = list(spec.submodule_search_locations or ()) if spec else []
    for location in locations:
        folder = Path(location, *rest)
        if (folder / "__init__.py").is_file():
            return folder
    raise ValueError(f"{package}: not a package")


def choices(package: str) -> tuple[str, ...]:
    """The names of the modules and sub-packages of ``package``, sorted, found by listing its
    directory (nothing is imported); names starting with ``_`` are not choices."""
    names = set()
    for entry in _folder(package).iterdir():
        if entry.name.startswith("_"):
            continue
        if entry.suffix == ".py" and entry.is_file():
            names.add(entry.stem)
        elif entry.is_dir() and (entry / "__init__.py").is_file():
            names.add(entry.name)
    return tuple(sorted(names))


def load(package: str, name: str) -> types.ModuleType:
    """The module ``package.name``; InputError naming the choices when ``name`` is not one."""
    known = choices(package)
    if name not in known:
        raise InputError(f"{name!r}: unknown in {package} (known: {', '.join(known)})")
    return importlib.import_module(f"{package}.{name}")
