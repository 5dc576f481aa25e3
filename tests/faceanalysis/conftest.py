"""Fixtures shared by the faceanalysis tests: the face model and an analysed subject."""

from __future__ import annotations

import pytest


@pytest.fixture(scope="session")
def model():
    from synth.model import FaceModel

    return FaceModel.default()


@pytest.fixture(scope="session")
def subject(tmp_path_factory):
    """Identity 101 smiling, rendered and analysed (the analysis folder)."""
    from faceanalysis.analysis.pipeline import analyze_to_folder
    from synth.render.sequence import render_sequence

    root = tmp_path_factory.mktemp("subject")
    files = render_sequence(root / "input", frames=12, size=256, seed=101,
                            expression="happiness", flow=False)
    analyze_to_folder(files["video"], root / "analysis")
    return root, files


@pytest.fixture
def other_video(tmp_path):
    """A 128x96 clip of three black frames: a video that is not the subject's."""
    import cv2
    import numpy as np

    path = tmp_path / "other.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10, (128, 96))
    for _ in range(3):
        writer.write(np.zeros((96, 128, 3), np.uint8))
    writer.release()
    return path
