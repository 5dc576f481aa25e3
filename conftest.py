"""Repository-wide pytest hooks.

Doctests that need an optional extra: a module names them in ``__doctest_requires__``
(the pytest-doctestplus convention), a mapping from a name or a tuple of names, relative
to the module and matched as fnmatch patterns (a class's pattern also covers its
methods), to the top-level modules they need, e.g.
``{("potential_batch", "TorchTracker"): ("torch", "kornia")}``. Where one of those
modules is not installed, the doctest is skipped and the reason names it; where all
are, the doctest runs as written.
"""

from __future__ import annotations

import importlib.util
from fnmatch import fnmatchcase

import pytest


def _installed(module: str) -> bool:
    try:
        return importlib.util.find_spec(module) is not None
    except (ImportError, ValueError):  # a dotted name whose parent is missing
        return False


def _matches(name: str, pattern: str) -> bool:
    return fnmatchcase(name, pattern) or fnmatchcase(name.split(".", 1)[0], pattern)


def _missing_requirements(dtest) -> list[str]:
    requires = dtest.globs.get("__doctest_requires__")
    if not requires:
        return []
    module = dtest.globs.get("__name__", "")
    name = dtest.name[len(module) + 1:] if dtest.name.startswith(module + ".") else ""
    if not name:
        return []
    needed: list[str] = []
    for patterns, modules in requires.items():
        patterns = (patterns,) if isinstance(patterns, str) else patterns
        if any(_matches(name, p) for p in patterns):
            needed += [m for m in ((modules,) if isinstance(modules, str) else modules)
                       if m not in needed]
    return [m for m in needed if not _installed(m)]


def pytest_collection_modifyitems(config, items):
    for item in items:
        dtest = getattr(item, "dtest", None)  # a DoctestItem
        if dtest is None:
            continue
        missing = _missing_requirements(dtest)
        if missing:
            item.add_marker(pytest.mark.skip(
                reason=f"doctest needs {', '.join(missing)} (not installed)"))
