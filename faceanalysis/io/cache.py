"""On-disk cache of tables derived from the face model (fiducial response, flow templates).

A cached table is only as good as the code that made it, so keys include a digest of
that code: editing the physics, the renderer or the tracker makes the old tables stale.
"""

from __future__ import annotations

import hashlib
import importlib.util
import os
from collections.abc import Iterable
from functools import lru_cache
from pathlib import Path


def cache_dir() -> Path:
    """Folder for cached tables: ``$FACEANALYSIS_CACHE`` or ``~/.cache/faceanalysis``."""
    root = os.environ.get("FACEANALYSIS_CACHE")
    return Path(root) if root else Path.home() / ".cache" / "faceanalysis"


@lru_cache(maxsize=8)
def source_digest(packages: tuple[str, ...], modules: tuple[str, ...] = ()) -> str:
    """SHA-1 of the sources of ``packages`` (``.py``, ``.toml``, ``.json``) and of the
    ``modules`` named (e.g. ``"faceanalysis.flow.templates"``)."""
    h = hashlib.sha1()
    for pkg in packages:
        spec = importlib.util.find_spec(pkg)
        if spec is None or not spec.submodule_search_locations:
            continue
        root = Path(next(iter(spec.submodule_search_locations)))
        for pattern in ("*.py", "*.toml", "*.json"):
            for f in sorted(root.rglob(pattern)):
                h.update(f.read_bytes())
    for name in modules:
        h.update(Path(importlib.util.find_spec(name).origin).read_bytes())
    return h.hexdigest()


def digest_of(parts: Iterable[bytes]) -> str:
    """Short key from byte strings."""
    h = hashlib.sha1()
    for part in parts:
        h.update(part)
    return h.hexdigest()[:16]
