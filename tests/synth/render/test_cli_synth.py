"""``faceanalysis synth`` through faceanalysis.cli.main.main."""

import json

import pandas as pd
import pytest

from faceanalysis.cli.main import main
from synth.render import sequence
from tests.synth.render._kinematic import KinematicFace


@pytest.fixture
def kinematic(monkeypatch):
    """Drive the command with the kinematic test face instead of the physics model."""
    monkeypatch.setattr(sequence, "_model_for", lambda seed, res, spread: (KinematicFace(),
                                                                          None))


def test_synth_expression_writes_all_files(tmp_path, kinematic):
    out = tmp_path / "out"
    rc = main(["synth", "--expression", "happiness", "--frames", "4", "--size", "64",
               "--seed", "3", "--supersample", "1", "-q", "-o", str(out)])
    assert rc == 0
    names = sorted(p.name for p in out.iterdir())
    assert "truth.csv" in names and "flow.npz" in names and "meta.json" in names
    assert "video.mp4" in names or "video.avi" in names
    truth = pd.read_csv(out / "truth.csv")
    assert len(truth) == 4
    assert truth.zygomaticus_major_l.max() > 0.5          # happiness -> AU12
    assert "AU12_r" in truth.columns
    meta = json.loads((out / "meta.json").read_text())
    assert meta["source"] == {"expression": "happiness", "intensity": 1.0}
    assert meta["size"] == [64, 64]


def test_synth_refuses_non_empty_output(tmp_path, kinematic, capsys):
    out = tmp_path / "out"
    out.mkdir()
    (out / "old.txt").write_text("x")
    rc = main(["synth", "--au", "12:0.8,6:0.5", "--frames", "2", "--size", "48x40",
               "--supersample", "1", "-q", "-o", str(out)])
    assert rc == 1
    assert "overwrite" in capsys.readouterr().err
    rc = main(["synth", "--au", "12:0.8,6:0.5", "--frames", "2", "--size", "48x40",
               "--supersample", "1", "--head-motion", "--noise", "--overwrite", "-q",
               "-o", str(out)])
    assert rc == 0
    meta = json.loads((out / "meta.json").read_text())
    assert meta["size"] == [48, 40] and meta["degradation"]["noise_std"] == 2.0
    assert meta["head_motion"]["amplitude"] == 1.0


def test_synth_contractions_csv_and_errors(tmp_path, kinematic, capsys):
    csv = tmp_path / "c.csv"
    pd.DataFrame({"frame": [0, 1, 2], "zygomaticus_major_l": [0, 0.3, 0.6],
                  "jaw_rotation": [0, 0.05, 0.1]}).to_csv(csv, index=False)
    rc = main(["synth", "--contractions", str(csv), "--size", "48", "--supersample", "1",
               "--flow-float16", "-q", "-o", str(tmp_path / "o1")])
    assert rc == 0
    assert len(pd.read_csv(tmp_path / "o1" / "truth.csv")) == 3
    import numpy as np

    with np.load(tmp_path / "o1" / "flow.npz") as z:
        assert z["flow"].dtype == np.float16 and z["flow"].shape == (2, 48, 48, 2)
    # usage errors: argparse's usage line, exit 2
    with pytest.raises(SystemExit) as exc:
        main(["synth", "--expression", "boredom", "-q", "-o", str(tmp_path / "o2")])
    assert exc.value.code == 2 and "boredom" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exc:
        main(["synth", "--au", "12=1", "-q", "-o", str(tmp_path / "o3")])
    assert exc.value.code == 2
    with pytest.raises(SystemExit):
        main(["synth", "--size", "ten", "-o", str(tmp_path / "o4")])
    with pytest.raises(SystemExit):
        main(["synth", "--expression", "surprise", "--au", "1:1", "-o", str(tmp_path / "o5")])


def test_synth_command_with_the_physics_model(tmp_path):
    out = tmp_path / "surprise"
    rc = main(["synth", "--expression", "surprise", "--frames", "3", "--size", "64",
               "--seed", "3", "-q", "-o", str(out)])
    assert rc == 0
    truth = pd.read_csv(out / "truth.csv")
    assert len(truth) == 3 and "frontalis_inner_l" in truth.columns
    meta = json.loads((out / "meta.json").read_text())
    assert meta["identity"]["shape"] is not None and meta["seed"] == 3
    # truth.csv is a valid contractions.csv for the analysis
    from faceanalysis.io.table import read_contractions

    table = read_contractions(out / "truth.csv")
    assert len(table) == 3 and "AU01_r" in table.columns
