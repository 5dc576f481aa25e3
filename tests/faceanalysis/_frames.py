"""The decoded frames of a rendered expression, for tests that arrange them as photographs,
image folders or a scene of their own."""

from __future__ import annotations

import cv2


def rendered_frames(folder, *, expression: str, frames: int, size: int, seed: int) -> list:
    """The ``frames`` BGR frames of ``synth``'s video of ``expression`` (written in
    ``folder``), as decoded: what a user's video of that face would give."""
    from synth.render.sequence import render_sequence

    files = render_sequence(folder, expression=expression, frames=frames, size=size,
                            seed=seed, flow=False)
    capture = cv2.VideoCapture(str(files["video"]))
    try:
        return [capture.read()[1] for _ in range(frames)]
    finally:
        capture.release()
