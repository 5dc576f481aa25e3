"""A rendered face saved as a 'photograph' for the photo-face tests (tests make their own
data), and the skip when the landmark model cannot be obtained."""

from pathlib import Path

import cv2
import pytest


def models_or_skip() -> None:
    """Skip the test when MediaPipe's face models cannot be obtained here."""
    from trackers.landmarks import ensure_models

    try:
        ensure_models()
    except (RuntimeError, FileNotFoundError) as exc:
        pytest.skip(f"the MediaPipe face models cannot be obtained here: {exc}")


def rendered_photograph(path: Path, *, seed: int, size) -> Path:
    """A neutral procedural face written as an image file at ``path``; skips the test when
    the landmark model that finds faces in photographs cannot be obtained."""
    models_or_skip()
    from synth.render.sequence import synthesize

    img = synthesize(frames=1, size=size, seed=seed, flow=False, texture_size=512).images[0]
    cv2.imwrite(str(path), cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
    return path
