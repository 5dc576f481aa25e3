"""The analysis does not depend on the bit depth the frames are stored in."""

import cv2
import numpy as np
import pandas as pd
import pytest

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


def test_alpha_and_float_pictures_give_the_analysis_of_their_eight_bit_colour(tmp_path):
    """PNGs with an alpha channel (screenshots, exported frames) and float TIFFs in [0, 1]
    are the same pictures: the default (landmark) tracker reads them as their RGB; a float
    TIFF in 0..255 is refused by name, where it would have read as white frames."""
    from PIL import Image

    from tests.faceanalysis._frames import rendered_frames

    frames = rendered_frames(tmp_path / "render", expression="happiness", frames=4, size=128,
                             seed=7)
    folders = {k: tmp_path / k for k in ("bgr", "bgra", "grey", "grey_alpha", "float", "float255")}
    for folder in folders.values():
        folder.mkdir()
    for n, frame in enumerate(frames):
        grey = cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY)
        opaque = np.full(grey.shape, 255, np.uint8)
        cv2.imwrite(str(folders["bgr"] / f"f{n}.png"), frame)
        cv2.imwrite(str(folders["bgra"] / f"f{n}.png"), np.dstack([frame, opaque]))
        cv2.imwrite(str(folders["grey"] / f"f{n}.png"), grey)
        Image.fromarray(np.dstack([grey, opaque]), "LA").save(folders["grey_alpha"] / f"f{n}.png")
        cv2.imwrite(str(folders["float"] / f"f{n}.tif"), frame.astype(np.float32) / 255)
        cv2.imwrite(str(folders["float255"] / f"f{n}.tif"), frame.astype(np.float32))
    assert cv2.imread(str(folders["bgra"] / "f0.png"), cv2.IMREAD_UNCHANGED).shape[2] == 4
    colour = analyze(folders["bgr"])
    assert colour.table["success"].all()
    for name in ("bgra", "float"):
        pd.testing.assert_frame_equal(analyze(folders[name]).table, colour.table)
    pd.testing.assert_frame_equal(analyze(folders["grey_alpha"]).table,
                                  analyze(folders["grey"]).table)
    with pytest.raises(ValueError, match=r"f0\.tif \(frame 0\): float pixels must lie in "
                                         r"\[0, 1\], got values in \[\d+, 2\d\d\]"):
        analyze(folders["float255"])


def test_a_photograph_of_another_size_is_analysed_as_at_the_first_size(tmp_path):
    """Photographs may each have their own size: one stored at twice the first's size is
    shrunk onto its canvas and reads exactly as stored at that size, where it was lost."""
    from tests.faceanalysis._frames import rendered_frames

    frames = rendered_frames(tmp_path / "render", expression="happiness", frames=3, size=128,
                             seed=7)
    same, mixed = tmp_path / "same", tmp_path / "mixed"
    for folder in (same, mixed):
        folder.mkdir()
    for n, frame in enumerate(frames):
        cv2.imwrite(str(same / f"p{n}.png"), frame)
        big = cv2.resize(frame, None, fx=2, fy=2, interpolation=cv2.INTER_NEAREST)
        cv2.imwrite(str(mixed / f"p{n}.png"), big if n == 2 else frame)
    at_size, placed = analyze(same), analyze(mixed)
    assert placed.table["success"].all()
    pd.testing.assert_frame_equal(placed.table, at_size.table)
    assert placed.metadata["input"]["placed"] == {
        "2": {"file": "p2.png", "size": [256, 256], "scale": [0.5, 0.5],
              "offset": [-0.25, -0.25]}}
