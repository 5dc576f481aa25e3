"""The standard suite with a photo suite beside it (faceanalysis.evaluation.suite)."""

import json

import cv2
import numpy as np
import pytest

from tests.faceanalysis._photos import rendered_photograph


@pytest.fixture(scope="module")
def photos(tmp_path_factory):
    folder = tmp_path_factory.mktemp("photos")
    rendered_photograph(folder / "person7.png", seed=7, size=240)
    return folder


def test_photo_suite_is_reported_beside_the_procedural_one(tmp_path, photos):
    from faceanalysis.evaluation.suite import SuiteConfig, photographs, run_suite

    config = SuiteConfig(identities=1, frames=5, sequences=(("au", "12:0.8,26:0.5"),),
                         faces=photographs(photos), tracker="landmarks", size=128)
    report = run_suite(tmp_path / "suite", config=config, estimators=("joint",))
    assert report["failures"] == []
    assert report["suite"]["tracker"] == "landmarks"
    photo = report["photo"]
    assert photo["faces"] == [str(photos / "person7.png")]
    assert [s["sequence"] for s in photo["sequences"]] == ["photo_person7_au_12-0.8_26-0.5"]
    zyg = photo["estimators"]["joint"]["controls"]["zygomaticus_major_l"]
    assert zyg["truth_max"] > 0.7 and zyg["rmse"] is not None
    assert "zygomaticus_major_l" in report["estimators"]["joint"]["controls"]
    md = (tmp_path / "suite" / "report.md").read_text()
    assert "## Procedural faces" in md and "## Photographed faces (1 people)" in md
    assert json.loads((tmp_path / "suite" / "report.json").read_text())["photo"]
    assert (tmp_path / "suite" / "report.png").stat().st_size > 0
    video = tmp_path / "suite" / "sequences" / "photo_person7_au_12-0.8_26-0.5"
    assert (video / "truth.csv").is_file()


def test_a_photograph_without_a_face_stops_the_suite_before_rendering(tmp_path, photos):
    from faceanalysis.evaluation.suite import SuiteConfig, run_suite

    wall = tmp_path / "wall.png"
    cv2.imwrite(str(wall), np.full((160, 160, 3), 128, np.uint8))
    with pytest.raises(ValueError, match="wall.png: no face"):
        run_suite(tmp_path / "suite", config=SuiteConfig(identities=1, frames=4,
                                                         faces=(str(wall),)))
    assert not (tmp_path / "suite").exists()
