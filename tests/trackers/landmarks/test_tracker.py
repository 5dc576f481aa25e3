import numpy as np
import pytest

from tests.trackers.landmarks.conftest import scene
from trackers.landmarks import LandmarkTracker


def _centre(lm):
    return (lm.box[0] + lm.box[2]) / 2


def test_none_on_blank_frames_then_the_face_is_picked_up_and_tracked(face):
    img, corners = face
    tracker = LandmarkTracker()
    blank = np.full_like(img, 128)
    assert tracker.track(blank) is None and tracker.track(blank) is None
    first, second = tracker.track(img), tracker.track(img)
    assert first.detected and not second.detected
    assert first.points.shape == (468, 2) and first.z.shape == (468,) and second.presence > 0.9
    iod = np.linalg.norm(second.points[263] - second.points[33])
    assert np.linalg.norm(second.points[[61, 291]] - corners, axis=1).max() < 0.1 * iod
    assert tracker.track(blank) is None
    assert tracker.track(img).detected


def test_the_largest_face_first_then_the_same_face(face):
    img, _ = face
    tracker = LandmarkTracker()
    assert _centre(tracker.track(scene(img))) < 320           # the larger face, at the left
    tracker.reset()
    small = tracker.track(scene(img, big=False))
    assert small.detected and _centre(small) > 320
    both = tracker.track(scene(img))                          # a larger face comes in
    assert _centre(both) > 320 and not both.detected
    assert tracker.track(scene(img, big=False, small=False)) is None
    back = tracker.track(scene(img))                           # lost, then both reappear
    assert back.detected and _centre(back) > 320


def test_bad_settings_are_refused():
    with pytest.raises(ValueError, match="'auto', 'litert', 'opencv'"):
        LandmarkTracker(runtime="onnx")
    with pytest.raises(ValueError, match="'rgb', 'bgr'"):
        LandmarkTracker(channel_order="yuv")
    with pytest.raises(ValueError, match="min_presence"):
        LandmarkTracker(min_presence=0)
