"""photo_face's points: a photograph whose nasolabial furrow or chin boss shows no edge is
still fitted."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

import faceanalysis.tracking as tracking
from faceanalysis.io.table import FIDUCIALS
from faceanalysis.resynthesis import photo


def _fake_track(lost):
    fid = np.arange(2 * len(FIDUCIALS), dtype=float).reshape(1, -1, 2)
    for name in lost:
        fid[0, FIDUCIALS.index(name)] = np.nan

    def track(path, **kwargs):
        return _Tracks(success=np.array([True]), fiducials=fid,
                       landmarks=[np.zeros((468, 3))], heads=np.ones((1, 4)))
    return track


class _Tracks(SimpleNamespace):
    def __len__(self):
        return 1


@pytest.mark.parametrize("lost", [["furrow_top_l"], ["furrow_top_l", "furrow_top_r"],
                                  ["chin"], ["furrow_top_r", "chin"]])
def test_a_lost_furrow_top_or_chin_is_left_out_of_the_fit(monkeypatch, tmp_path, lost):
    monkeypatch.setattr(tracking, "track", _fake_track(lost))
    _, points = photo._tracked_points(tmp_path / "face.png")
    assert not set(lost) & set(points)
    assert set(FIDUCIALS) - set(lost) <= set(points)
    assert set(photo.MESH_LANDMARKS) <= set(points)


def test_a_lost_mouth_corner_is_still_an_error(monkeypatch, tmp_path):
    monkeypatch.setattr(tracking, "track", _fake_track(["mouth_corner_l", "furrow_top_r"]))
    with pytest.raises(ValueError, match="mouth_corner_l could not be placed"):
        photo._tracked_points(tmp_path / "face.png")
