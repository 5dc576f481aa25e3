"""contractions.csv: schema, round trip, validation messages, atomic writing, AU derivation."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from faceanalysis.io.table import (
    AU_COLUMNS,
    FIDUCIALS,
    HEAD_COLUMNS,
    IDENTIFIABLE_COLUMNS,
    JAW,
    MUSCLES,
    au_intensities,
    contraction_columns,
    empty_table,
    read_contractions,
    with_au_columns,
    with_identifiable_columns,
    write_contractions,
)


def filled_table(n=6, rng=None):
    rng = rng or np.random.default_rng(0)
    t = empty_table(n, frames=np.arange(10, 10 + n), timestamps=np.arange(n) / 30)
    t["success"] = 1
    t.loc[2, "success"] = 0
    t["confidence"] = rng.uniform(0, 1, n)
    t[list(HEAD_COLUMNS)] = rng.uniform(0, 200, (n, 4))
    fid = [c for c in contraction_columns() if c.startswith("fid_")]
    t[fid] = rng.uniform(0, 640, (n, len(fid)))
    t[list(MUSCLES)] = rng.uniform(0, 1, (n, len(MUSCLES)))
    t[JAW] = rng.uniform(-0.05, 0.3, n)
    t[list(IDENTIFIABLE_COLUMNS)] = rng.integers(0, 2, (n, len(IDENTIFIABLE_COLUMNS)))
    t[list(AU_COLUMNS)] = rng.uniform(0, 5, (n, len(AU_COLUMNS)))
    lost = [c for c in contraction_columns() if c not in ("frame", "timestamp", "success")]
    t.loc[2, lost] = np.nan
    return t.copy()   # one block per dtype, as a table read from a file


def test_schema_matches_design():
    assert len(FIDUCIALS) == 11 and FIDUCIALS[0] == "brow_inner_l" and FIDUCIALS[-1] == "chin"
    assert len(MUSCLES) == 29 and len(set(MUSCLES)) == 29
    for name in ("zygomaticus_major_l", "zygomaticus_major_r", "levator_labii_nasi_l",
                 "orbicularis_oris", "orbicularis_oculi_l", "orbicularis_oculi_r", "risorius_r"):
        assert name in MUSCLES
    cols = contraction_columns()
    assert cols[:8] == ["frame", "timestamp", "success", "confidence",
                        "head_x", "head_y", "head_scale", "head_roll"]
    assert cols[8:10] == ["head_pitch", "head_yaw"]
    assert cols[10:12] == ["eye_openness_l", "eye_openness_r"]
    assert cols[12:14] == ["fid_brow_inner_l_x", "fid_brow_inner_l_y"]
    assert cols.index(JAW) == cols.index("orbicularis_oculi_r") + 1
    assert cols[cols.index(JAW) + 1:][:len(AU_COLUMNS)] == list(AU_COLUMNS)
    assert AU_COLUMNS[0] == "AU01_r" and AU_COLUMNS[-1] == "AU27_r" and len(AU_COLUMNS) == 16
    assert cols[-len(IDENTIFIABLE_COLUMNS):] == list(IDENTIFIABLE_COLUMNS)
    assert IDENTIFIABLE_COLUMNS[0] == f"{MUSCLES[0]}_identifiable"
    assert IDENTIFIABLE_COLUMNS[-1] == "AU27_identifiable"
    assert len(cols) == len(set(cols)) == 4 + 4 + 2 + 2 + 22 + 29 + 1 + 16 + 30 + 16


def test_round_trip(tmp_path):
    t = filled_table()
    original = t.copy()
    t["note"] = "x"  # extra columns travel after the fixed ones
    path = write_contractions(t, tmp_path / "contractions.csv")
    back = read_contractions(path)
    assert list(back.columns) == contraction_columns() + ["note"]
    assert back["frame"].dtype == np.int64 and back["success"].tolist() == [1, 1, 0, 1, 1, 1]
    pd.testing.assert_frame_equal(back[contraction_columns()], original, check_dtype=False,
                                  atol=1e-3, rtol=0)
    assert back.loc[2, list(MUSCLES)].isna().all()
    np.testing.assert_allclose(back[list(MUSCLES)], original[list(MUSCLES)], atol=5e-7)
    np.testing.assert_allclose(back["timestamp"], original["timestamp"], atol=5e-7)
    pd.testing.assert_frame_equal(t.drop(columns="note"), original)  # input not modified


def test_file_format_is_fixed(tmp_path):
    t = filled_table(3)
    t = t[list(reversed(t.columns))]  # column order of the frame does not matter
    path = write_contractions(t, tmp_path / "c.csv")
    lines = path.read_text().splitlines()
    assert lines[0] == ",".join(contraction_columns())
    first = dict(zip(lines[0].split(","), lines[1].split(",")))
    assert first["frame"] == "10" and first["success"] == "1"
    assert 1 <= len(first["zygomaticus_major_l"].split(".")[1]) <= 6
    assert len(first["fid_chin_x"].split(".")[1]) <= 3
    assert "e" not in lines[1].lower()
    assert first["AU12_identifiable"] in ("0", "1")
    lost = dict(zip(lines[0].split(","), lines[3].split(",")))
    assert lost["zygomaticus_major_l"] == "" and lost["success"] == "0"
    assert lost["AU12_identifiable"] == ""


def test_missing_file(tmp_path):
    with pytest.raises(FileNotFoundError, match=r"nope\.csv: no such file"):
        read_contractions(tmp_path / "nope.csv")


def test_missing_columns_are_named(tmp_path):
    t = filled_table().drop(columns=["risorius_l", "head_roll"])
    path = tmp_path / "c.csv"
    t.to_csv(path, index=False)
    with pytest.raises(ValueError, match=r"missing columns head_roll, risorius_l"):
        read_contractions(path)
    with pytest.raises(ValueError, match="missing columns"):
        write_contractions(t, tmp_path / "out.csv")
    assert not (tmp_path / "out.csv").exists()


def write_with(tmp_path, row, column, value):
    t = filled_table()
    path = tmp_path / "c.csv"
    write_contractions(t, path)
    df = pd.read_csv(path, dtype=str, keep_default_na=False)
    df.loc[row, column] = value
    df.to_csv(path, index=False)
    return path


@pytest.mark.parametrize(("row", "column", "value", "match"), [
    (3, "zygomaticus_major_l", "abc", r"line 5 \(frame 13\), column zygomaticus_major_l: "
                                     r"'abc' is not a number"),
    (1, "corrugator_r", "1.5", r"line 3 \(frame 11\), column corrugator_r: 1.5 is outside"),
    (4, "orbicularis_oris", "-0.1", r"frame 14\), column orbicularis_oris: -0.1 is outside"),
    (0, "AU12_r", "6", r"frame 10\), column AU12_r: 6 is outside \[0, 5\]"),
    (0, "confidence", "1.2", r"column confidence"),
    (5, "success", "2", r"frame 15\), column success: 2 is not 0 or 1"),
    (1, "risorius_l_identifiable", "0.5",
     r"frame 11\), column risorius_l_identifiable: 0.5 is not 0 or 1"),
    (5, "frame", "12", r"line 7 \(frame 12\), column frame: frame numbers must increase"),
    (2, "timestamp", "", r"frame 12\), column timestamp: empty cell"),
    (1, "fid_chin_x", "1,2", r"column fid_chin_x: '1,2' is not a number"),
])
def test_bad_cells_are_named(tmp_path, row, column, value, match):
    path = write_with(tmp_path, row, column, value)
    with pytest.raises(ValueError, match=match):
        read_contractions(path)


def test_write_refuses_out_of_range_values_and_leaves_no_file(tmp_path):
    t = filled_table()
    t.loc[4, "mentalis_l"] = 1.01
    with pytest.raises(ValueError, match=r"frame 14\), column mentalis_l"):
        write_contractions(t, tmp_path / "c.csv")
    assert list(tmp_path.iterdir()) == []


def test_empty_and_garbage_files(tmp_path):
    empty = tmp_path / "empty.csv"
    empty.write_text("")
    with pytest.raises(ValueError, match=r"empty\.csv: file is empty"):
        read_contractions(empty)
    binary = tmp_path / "bin.csv"
    binary.write_bytes(np.random.default_rng(2).bytes(3000))
    with pytest.raises(ValueError, match=r"bin\.csv"):
        read_contractions(binary)


def test_interrupted_write_keeps_previous_file(tmp_path, monkeypatch):
    path = tmp_path / "contractions.csv"
    write_contractions(filled_table(3), path)
    before = path.read_bytes()

    def broken_to_csv(self, *args, **kwargs):
        target = args[0]
        with open(target, "w") as fh:
            fh.write("frame,timestamp\n0,0.0\n")  # half a table
        raise KeyboardInterrupt

    monkeypatch.setattr(pd.DataFrame, "to_csv", broken_to_csv)
    with pytest.raises(KeyboardInterrupt):
        write_contractions(filled_table(6), path)
    assert path.read_bytes() == before
    assert list(tmp_path.iterdir()) == [path]


def test_empty_table_validates():
    with pytest.raises(ValueError, match="non-negative"):
        empty_table(-1)
    with pytest.raises(ValueError, match="frames has 2 entries, expected 3"):
        empty_table(3, frames=[0, 1])
    assert len(empty_table(0)) == 0


# -- action units --------------------------------------------------------------------------

def test_names_agree_with_the_face_model():
    facs = pytest.importorskip("synth.facs")
    assert tuple(facs.MUSCLE_NAMES) == MUSCLES
    assert JAW == facs.JAW
    assert tuple(facs.au_column(n) for n in facs.CORE_AUS) == AU_COLUMNS


def test_au_intensities_recover_the_model_action_units(tmp_path):
    facs = pytest.importorskip("synth.facs")
    truth = [{12: 0.6, 4: 0.3, 26: 1.0}, {1: 0.5, 2: 0.5, 15: 0.8}, {}]
    t = empty_table(4)
    t[list(MUSCLES)] = 0.0
    t[JAW] = 0.0
    for row, aus in enumerate(truth):
        for name, value in facs.aus_to_contractions(aus).items():
            t.loc[row, name] = value
    t.loc[3, [*MUSCLES, JAW]] = np.nan  # a lost frame
    original = t.copy()
    out = with_au_columns(t)
    pd.testing.assert_frame_equal(t, original)
    for row, aus in enumerate(truth):
        for n in (1, 2, 4, 12, 15, 26):
            assert out.loc[row, f"AU{n:02d}_r"] == pytest.approx(5 * aus.get(n, 0.0), abs=1e-3)
    assert out.loc[3, list(AU_COLUMNS)].isna().all()
    values = out.loc[:2, list(AU_COLUMNS)].to_numpy()
    assert values.min() >= 0 and values.max() <= 5
    write_contractions(out.assign(timestamp=0.0), tmp_path / "c.csv")  # a valid table


def test_an_empty_muscle_empties_only_the_action_units_that_depend_on_it():
    facs = pytest.importorskip("synth.facs")
    t = empty_table(3)
    t[list(MUSCLES)] = 0.0
    t[JAW] = 0.0
    for row in range(3):
        for name, value in facs.aus_to_contractions({12: 0.6, 1: 0.4, 2: 0.2, 4: 0.3,
                                                     26: 1.0}).items():
            t.loc[row, name] = value
    t.loc[1, "frontalis_outer_l"] = np.nan        # a brow lost: AU 2, and AU 1 fitted with it
    t.loc[2, ["corrugator_r", JAW]] = np.nan      # AU 4 and the jaw's action units
    out = au_intensities(t)
    full = out.loc[0]
    assert out.loc[1, ["AU01_r", "AU02_r"]].isna().all()
    assert out.loc[2, ["AU04_r", "AU25_r", "AU26_r", "AU27_r"]].isna().all()
    # every other action unit keeps the value it has with every muscle present
    for row, gone in ((1, {"AU01_r", "AU02_r"}), (2, {"AU04_r", "AU25_r", "AU26_r", "AU27_r"})):
        kept = [c for c in AU_COLUMNS if c not in gone]
        np.testing.assert_allclose(out.loc[row, kept].to_numpy(float),
                                   full[kept].to_numpy(float), atol=1e-9)
    assert out.loc[1, "AU12_r"] == pytest.approx(3.0, abs=1e-3)
    assert out.loc[2, "AU01_r"] == pytest.approx(2.0, abs=1e-3)


def test_au_intensities_reject_infinite_values():
    t = empty_table(2)
    t[list(MUSCLES)] = 0.0
    t.loc[1, "risorius_r"] = np.inf
    with pytest.raises(ValueError, match="infinite"):
        au_intensities(t)


def test_written_tables_with_lost_frames_are_read_back_by_every_reader(tmp_path):
    hypothesis = pytest.importorskip("hypothesis")
    st = pytest.importorskip("hypothesis.strategies")
    from faceanalysis.resynthesis.series import series_from_table

    @hypothesis.settings(max_examples=25, deadline=None, derandomize=True)
    @hypothesis.given(n=st.integers(1, 12), seed=st.integers(0, 2**32 - 1))
    def check(n, seed):
        rng = np.random.default_rng(seed)
        t = empty_table(n, timestamps=np.arange(n) / 25)
        success = rng.random(n) < 0.7
        t["success"] = success.astype(np.int64)
        t["confidence"] = np.where(success, rng.random(n), 0.0)
        t[list(HEAD_COLUMNS)] = rng.uniform(1, 200, (n, 4))
        t[[*MUSCLES]] = rng.random((n, len(MUSCLES)))
        t[JAW] = rng.uniform(0, 0.2, n)
        # lost frames: any pattern of empty cells, from none to all
        lost_cells = (rng.random((n, len(MUSCLES) + 1)) < rng.random()) & ~success[:, None]
        values = t[[*MUSCLES, JAW]].to_numpy()
        t[[*MUSCLES, JAW]] = np.where(lost_cells, np.nan, values)
        path = write_contractions(with_au_columns(t), tmp_path / "c.csv")
        back = read_contractions(path)
        series = series_from_table(back, str(path))
        assert back["success"].tolist() == success.astype(int).tolist()
        assert np.isfinite(series.controls).all() and np.isfinite(series.jaw).all()

    check()


def test_identifiable_flags_follow_the_assessment_and_the_observed_frames():
    t = filled_table(4)
    observed = np.ones((4, len(MUSCLES) + 1), dtype=bool)
    zyg_l = list(MUSCLES).index("zygomaticus_major_l")
    observed[3, zyg_l] = False                       # held on frame 3: not measured there
    out = with_identifiable_columns(t, ["zygomaticus_major_l", "zygomaticus_major_r", JAW],
                                    observed=observed)
    assert out["zygomaticus_major_l_identifiable"].tolist()[:2] == [1.0, 1.0]
    assert np.isnan(out.loc[2, "zygomaticus_major_l_identifiable"])      # lost frame
    assert out.loc[3, "zygomaticus_major_l_identifiable"] == 0.0
    assert out.loc[3, "zygomaticus_major_r_identifiable"] == 1.0
    assert out["risorius_l_identifiable"].tolist()[:2] == [0.0, 0.0]
    # an action unit is measured where every control it is derived from is
    assert out["AU12_identifiable"].tolist()[:2] == [1.0, 1.0]
    assert out.loc[3, "AU12_identifiable"] == 0.0
    assert out.loc[0, "AU26_identifiable"] == 1.0 and out.loc[0, "AU01_identifiable"] == 0.0
    assert t.equals(filled_table(4))                 # input untouched
    with pytest.raises(ValueError, match="unknown controls"):
        with_identifiable_columns(t, ["zygomaticus"])
    with pytest.raises(ValueError, match="observed must have shape"):
        with_identifiable_columns(t, [], observed=observed[:2])


def test_tables_without_identifiable_columns_are_read(tmp_path):
    t = filled_table().drop(columns=list(IDENTIFIABLE_COLUMNS))
    path = tmp_path / "c.csv"
    t.to_csv(path, index=False)
    back = read_contractions(path)
    assert back[list(IDENTIFIABLE_COLUMNS)].isna().all().all()


def test_measured_values_empty_what_the_flags_do_not_vouch_for():
    from faceanalysis.io.table import empty_table, measured_values

    t = empty_table(4)
    t["success"] = [1, 1, 1, 0]
    t["mentalis_l"] = [0.1, 0.2, 0.3, np.nan]
    t["mentalis_l_identifiable"] = [1, 0, np.nan, np.nan]       # the third: not known
    t["AU12_r"] = [1.0, 2.0, 3.0, np.nan]
    t["AU12_identifiable"] = [0, 1, 1, np.nan]
    before = t.copy()
    out = measured_values(t)
    assert out.index.equals(t.index) and "zygomaticus_major_l" in out and "AU12_r" in out
    np.testing.assert_array_equal(out["mentalis_l"], [0.1, np.nan, 0.3, np.nan])
    np.testing.assert_array_equal(out["AU12_r"], [np.nan, 2.0, 3.0, np.nan])
    pd.testing.assert_frame_equal(t, before)
    with pytest.raises(ValueError, match="no column"):
        measured_values(t.drop(columns="success"))


@pytest.mark.parametrize("resave", ["semicolon_decimal_comma", "semicolon", "tab", "bom_crlf"])
def test_a_table_re_saved_by_a_spreadsheet_reads_as_written(tmp_path, resave):
    """Spreadsheets where the comma is the decimal separator save "CSV" with semicolons and
    decimal commas; others save tabs, or a byte-order mark and CRLF line ends."""
    from faceanalysis.evaluation.scores import evaluate

    path = write_contractions(filled_table(), tmp_path / "contractions.csv")
    written = read_contractions(path)
    table = pd.read_csv(path)
    again = tmp_path / "again.csv"
    if resave == "bom_crlf":
        again.write_bytes(b"\xef\xbb\xbf" + path.read_bytes().replace(b"\n", b"\r\n"))
    else:
        sep = "\t" if resave == "tab" else ";"
        table.to_csv(again, index=False, sep=sep,
                     decimal="," if resave == "semicolon_decimal_comma" else ".")
    pd.testing.assert_frame_equal(read_contractions(again), written)
    scores = evaluate(path, again)        # the file scored against itself as written
    assert scores["frames_compared"] == 5 and scores["fiducial_error_px"] == 0


def test_a_bad_cell_in_a_semicolon_table_is_named(tmp_path):
    path = write_contractions(filled_table(), tmp_path / "contractions.csv")
    table = pd.read_csv(path).astype({"zygomaticus_major_l": object})
    table.loc[3, "zygomaticus_major_l"] = "0,3x"
    table.to_csv(tmp_path / "bad.csv", index=False, sep=";", decimal=",")
    with pytest.raises(ValueError, match=r"line 5 \(frame 13\), column zygomaticus_major_l: "
                                         "'0,3x' is not a number"):
        read_contractions(tmp_path / "bad.csv")
