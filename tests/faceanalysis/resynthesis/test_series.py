"""The time series a resynthesis plays: cells checked, lost frames held."""

from __future__ import annotations

import numpy as np
import pytest

from faceanalysis.io.table import MUSCLES, empty_table, write_contractions
from faceanalysis.resynthesis.pipeline import resynthesize
from tests.faceanalysis.resynthesis._series import SMILE, _drive


@pytest.mark.parametrize("cell, column, message", [
    ("1.5", SMILE[0], r"line 4 \(frame 2\), column zygomaticus_major_l: 1.5 is outside"),
    ("abc", SMILE[1], r"line 4 \(frame 2\), column zygomaticus_major_r: 'abc' is not a number"),
    ("-0.1", "jaw_rotation", r"line 4 \(frame 2\), column jaw_rotation: -0.1 is outside"),
    ("", SMILE[0], r"line 4 \(frame 2\), column zygomaticus_major_l: an empty cell"),
])
def test_bad_cells_are_named_by_row_and_column(tmp_path, model, cell, column, message):
    df = _drive().astype(object)
    df["frame"] = range(4)
    df.loc[2, column] = cell
    csv = tmp_path / "bad.csv"
    df.to_csv(csv, index=False)
    with pytest.raises(ValueError, match=message):
        resynthesize(csv, model=model)


def test_full_table_goes_through_read_contractions(tmp_path, model):
    t = empty_table(3, timestamps=[0.0, 0.04, 0.08])
    t["success"] = 1
    t["confidence"] = 1.0
    t[list(MUSCLES)] = 0.0
    t["jaw_rotation"] = 0.0
    t.loc[1, SMILE[0]] = 2.0
    path = tmp_path / "contractions.csv"
    t.to_csv(path, index=False)
    with pytest.raises(ValueError, match=r"line 3 \(frame 1\), column zygomaticus_major_l"):
        resynthesize(path, model=model)
    t.loc[1, SMILE[0]] = 0.5
    write_contractions(t, path)
    res = resynthesize(tmp_path, model=model, size=48, shading="plain")   # the folder works too
    assert len(list(res)) == 3
    assert res.fps == pytest.approx(25.0)       # from the timestamps


def test_lost_frames_hold_the_last_good_value(model):
    df = _drive(5)
    df["success"] = [1, 1, 0, 0, 1]
    df.loc[2, SMILE[0]] = np.nan                 # lost frames may be empty
    df.loc[3, [SMILE[0], SMILE[1]]] = 0.9        # ...or hold garbage: both are ignored
    states = list(resynthesize(df, model=model, size=48, shading="plain").states())
    np.testing.assert_allclose(states[2].vertices, states[1].vertices)
    np.testing.assert_allclose(states[3].vertices, states[1].vertices)
    assert np.abs(states[4].vertices - states[1].vertices).max() > 1e-3
    assert np.abs(states[1].vertices - states[0].vertices).max() > 1e-3


def test_a_misspelt_muscle_column_is_named_unknown(tmp_path):
    from faceanalysis.resynthesis.series import series_from_table

    df = _drive().rename(columns={SMILE[0]: "zygomaticus_majr_l"})
    with pytest.raises(ValueError, match="unknown column 'zygomaticus_majr_l' "
                                         r"\(did you mean 'zygomaticus_major_l'\?\)"):
        series_from_table(df, "drive.csv")


def test_a_cut_down_table_without_success_holds_its_empty_rows(tmp_path):
    """A table cut down to a few columns (frame, a muscle pair) loses its success column:
    a row with every control empty is a lost frame, as contractions.csv writes one, and an
    empty cell beside filled ones is still refused."""
    from faceanalysis.resynthesis.series import load_series

    df = _drive(5).astype(object)
    df.insert(0, "frame", range(5))
    df.loc[2, [*SMILE, "jaw_rotation"]] = ""
    csv = tmp_path / "cut.csv"
    df.to_csv(csv, index=False)
    series = load_series(csv)
    assert series.success.tolist() == [True, True, False, True, True]
    np.testing.assert_allclose(series.controls[2], series.controls[1])
    df.loc[2, SMILE[0]] = 0.5
    df.to_csv(csv, index=False)
    with pytest.raises(ValueError, match=r"line 4 \(frame 2\), column zygomaticus_major_r: an "
                                         r"empty cell in a tracked frame \(other controls are "
                                         "given on that line\\)"):
        load_series(csv)
