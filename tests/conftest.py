"""Shared fixtures. Tests make their own data; ``../shared`` is only used by tests
marked ``real_data``, which skip cleanly when it is absent."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parent.parent
SHARED_REAL = Path(
    os.environ.get("FACEANALYSIS_REAL_DATA", REPO.parent / "shared" / "data" / "real")
)


@pytest.fixture
def rng() -> np.random.Generator:
    """A seeded generator, so that every test run sees the same numbers."""
    return np.random.default_rng(12345)


@pytest.fixture
def real_video_dir() -> Path:
    """Folder of real face videos beside the repository; skips the test when absent."""
    if not SHARED_REAL.is_dir() or not any(SHARED_REAL.glob("*.mp4")):
        pytest.skip(f"real videos not found in {SHARED_REAL}")
    return SHARED_REAL


@pytest.fixture
def run_cli(capsys):
    """Run the ``faceanalysis`` command in-process; returns (exit code, stdout, stderr)."""
    from faceanalysis.cli.main import main

    def _run(*argv: str) -> tuple[int, str, str]:
        try:
            code = main([str(a) for a in argv])
        except SystemExit as exc:  # argparse exits for --help, --version and usage errors
            code = exc.code if isinstance(exc.code, int) else 1
        out, err = capsys.readouterr()
        return code, out, err

    return _run
