"""Property: whatever valid input ``analyze`` gets (a rendered face with random contractions,
8 or 16 bits, a frame range, lost frames), every file it writes is read back by
``read_contractions``, by the resynthesis reader and by ``evaluate``."""

import cv2
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from faceanalysis.analysis.pipeline import analyze_to_folder
from faceanalysis.evaluation.scores import evaluate
from faceanalysis.io.table import read_contractions
from faceanalysis.resynthesis.series import load_series
from synth.render.sequence import render_sequence

AU_SCRIPTS = ("12:0.8,6:0.5", "1:0.9,2:0.7", "4:0.8,15:0.6", "26:0.7", "9:0.8,2:0.5")


@pytest.mark.slow
@settings(max_examples=4, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(au=st.sampled_from(AU_SCRIPTS), seed=st.integers(101, 140),
       sixteen_bit=st.booleans(), start=st.integers(0, 2), n=st.integers(3, 5),
       lost=st.sets(st.integers(1, 7), max_size=2))
def test_every_file_analyze_writes_is_read_back(tmp_path_factory, au, seed, sixteen_bit,
                                                start, n, lost):
    root = tmp_path_factory.mktemp("chain")
    files = render_sequence(root / "seq", au=au, frames=8, size=192, seed=seed, flow=False)
    cap = cv2.VideoCapture(str(files["video"]))
    frames = [cap.read()[1] for _ in range(8)]
    folder = root / "frames"
    folder.mkdir()
    for i, f in enumerate(frames):
        if i in lost and i != start:            # a blank frame: the face is lost there
            f = np.full_like(f, 128)
        if sixteen_bit:
            f = f.astype(np.uint16) * 257
        cv2.imwrite(str(folder / f"{i:03d}.png"), f)
    out = root / "analysis"
    analyze_to_folder(folder, out, start=start, end=start + n)

    table = read_contractions(out / "contractions.csv")
    assert len(table) == n and table["frame"].tolist() == list(range(start, start + n))
    series = load_series(out)
    assert len(series.frames) == n
    report = evaluate(files["truth"], out, allow_partial=True)
    assert report["frames"] == n
