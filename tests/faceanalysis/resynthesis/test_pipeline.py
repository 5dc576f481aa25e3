"""Resynthesis: the face model driven by a contraction time series, rendered again."""

from __future__ import annotations

import logging

import numpy as np
import pandas as pd
import pytest

from faceanalysis.io.table import MUSCLES
from faceanalysis.resynthesis.pipeline import resynthesize
from tests.faceanalysis.resynthesis._series import SMILE, _drive


def test_partial_csv_drives_the_model_and_warns_about_missing_muscles(tmp_path, model, caplog):
    csv = tmp_path / "partial.csv"
    _drive().to_csv(csv, index=False)
    with caplog.at_level(logging.WARNING, logger="faceanalysis.resynthesis.pipeline"):
        res = resynthesize(csv, model=model, size=64, shading="plain")
    warned = " ".join(r.getMessage() for r in caplog.records)
    assert "frontalis_inner_l" in warned and "orbicularis_oris" in warned
    assert "zygomaticus_major_l" not in warned
    assert set(res.missing) == set(MUSCLES) - set(SMILE)
    frames = list(res)
    assert len(frames) == 4 and frames[0].shape == (64, 64, 3) and frames[0].dtype == np.uint8
    assert np.abs(frames[-1].astype(int) - frames[0]).max() > 30     # the face moved
    assert res.fps == 30.0


def test_options_are_checked(model):
    with pytest.raises(ValueError, match="view"):
        resynthesize(_drive(), model=model, view="top")
    with pytest.raises(ValueError, match="shading"):
        resynthesize(_drive(), model=model, shading="toon")
    with pytest.raises(ValueError, match="fps"):
        resynthesize(_drive(), model=model, fps=0)
    with pytest.raises(ValueError, match="no muscle columns"):
        resynthesize(pd.DataFrame({"frame": [0, 1]}), model=model)
    with pytest.raises(ValueError, match="side_by_side needs the input video"):
        resynthesize(_drive(), model=model, side_by_side=True)
