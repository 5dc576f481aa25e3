"""The names the packages share: the trackers' fiducials are the face mesh's landmarks, and
the table's columns are the face model's muscles and jaw."""

from faceanalysis.io.table import FIDUCIALS, JAW, MUSCLES
from synth.face_mesh import FIDUCIALS as MESH_FIDUCIALS
from synth.facs import JAW as SYNTH_JAW
from synth.facs import MUSCLE_NAMES
from synth.model import FaceModel
from trackers.fiducials import FIDUCIAL_NAMES


def test_the_table_reuses_the_names_of_the_packages_that_own_them():
    assert FIDUCIALS is FIDUCIAL_NAMES
    assert MUSCLES is MUSCLE_NAMES and JAW is SYNTH_JAW


def test_the_mesh_landmarks_are_the_trackers_fiducials():
    # trackers and synth are independent packages; this is where they must agree
    assert tuple(MESH_FIDUCIALS) == FIDUCIAL_NAMES


def test_the_default_model_has_the_table_muscles():
    assert tuple(FaceModel.default().muscle_names) == MUSCLES
