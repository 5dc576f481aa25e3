"""The analysis does not depend on the bit depth the frames are stored in."""

import cv2
import numpy as np
import pandas as pd

from faceanalysis.analysis.pipeline import analyze


def _frames_to_folders(video, folder8, folder16):
    folder8.mkdir()
    folder16.mkdir()
    capture = cv2.VideoCapture(str(video))
    n = 0
    while True:
        ok, frame = capture.read()
        if not ok:
            break
        cv2.imwrite(str(folder8 / f"f{n:03d}.png"), frame)
        cv2.imwrite(str(folder16 / f"f{n:03d}.png"), frame.astype(np.uint16) * 257)
        n += 1
    capture.release()
    return n


def test_sixteen_bit_frames_give_the_same_analysis_as_their_eight_bit_originals(tmp_path):
    from synth.render.sequence import render_sequence

    files = render_sequence(tmp_path / "render", expression="happiness", frames=5, size=128,
                            seed=7, flow=False)
    n = _frames_to_folders(files["video"], tmp_path / "u8", tmp_path / "u16")
    assert n == 5
    check = cv2.imread(str(tmp_path / "u16" / "f000.png"), cv2.IMREAD_UNCHANGED)
    assert check.dtype == np.uint16
    eight = analyze(tmp_path / "u8")
    sixteen = analyze(tmp_path / "u16")
    assert eight.table["success"].sum() > 0
    pd.testing.assert_frame_equal(eight.table, sixteen.table)
    np.testing.assert_array_equal(eight.fiducials, sixteen.fiducials)
