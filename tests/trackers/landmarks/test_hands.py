import numpy as np
import pytest

from tests.trackers.landmarks.conftest import face, models, scene  # noqa: F401 (fixtures)
from trackers.landmarks.detection import decode_ssd, ssd_anchors
from trackers.landmarks.hands import (
    HandTracker,
    PalmDetection,
    hand_landmarks,
    hand_roi_transform,
    palm_roi_transform,
)


def _crop_point(m, uv):
    return m[:, :2] @ np.asarray(uv, float) + m[:, 2]


def test_anchor_grids_of_the_face_and_palm_detectors():
    assert ssd_anchors(16).shape == (896, 2)     # the face detector's outputs
    assert ssd_anchors(24).shape == (2016, 2)    # the palm detector's
    a = ssd_anchors(24)
    assert a.min() > 0 and a.max() < 1
    np.testing.assert_allclose(a[0], [0.5 / 24, 0.5 / 24])


def test_decoding_one_confident_anchor():
    anchors = ssd_anchors(24)
    regressors = np.zeros((1, len(anchors), 18), np.float32)
    logits = np.full((1, len(anchors), 1), -20, np.float32)
    k = 700
    logits[0, k] = 5.0
    # box centre moved 10 px right of the anchor, 40 x 20 px; keypoint 0 3 px below it
    regressors[0, k, :4] = [10, 0, 40, 20]
    regressors[0, k, 5] = 3
    (box, kp, score), = decode_ssd(regressors, logits, anchors, 192, 0.5)
    cx, cy = anchors[k] + np.array([10, 0]) / 192
    np.testing.assert_allclose(box, [cx - 20 / 192, cy - 10 / 192, cx + 20 / 192,
                                     cy + 10 / 192], atol=1e-6)
    np.testing.assert_allclose(kp[0], anchors[k] + np.array([0, 3]) / 192, atol=1e-6)
    assert kp.shape == (7, 2) and score == pytest.approx(1 / (1 + np.exp(-5.0)))
    assert decode_ssd(regressors, logits, anchors, 192, 0.995) == []


def test_the_hand_crop_from_an_upright_palm():
    # wrist below the middle knuckle: the crop is not turned; it is centred half the
    # palm's height above the palm box and 2.6 times its longer side
    kp = np.array([[100, 140], [90, 100], [100, 98], [110, 100], [120, 104], [80, 130],
                   [75, 120]], float)
    m = palm_roi_transform(PalmDetection((80.0, 95.0, 120.0, 145.0), kp, 0.9))
    np.testing.assert_allclose(m[:, :2], 2.6 * 50 / 224 * np.eye(2), atol=1e-9)
    np.testing.assert_allclose(_crop_point(m, [111.5, 111.5]), [100, 120 - 25], atol=1e-9)


def test_the_hand_crop_turns_with_the_hand():
    rng = np.random.default_rng(0)
    hand = rng.uniform(-1, 1, (21, 2)) * [20, 30]
    hand[0], hand[9] = [0, 40], [0, -10]                 # wrist below, knuckle above
    upright = hand_roi_transform(hand + [200, 150])
    for turn in (30.0, 90.0, -120.0):
        t = np.radians(turn)
        rot = np.array([[np.cos(t), -np.sin(t)], [np.sin(t), np.cos(t)]])
        m = hand_roi_transform(hand @ rot.T + [200, 150])
        # the same crop turned about the image point (200, 150)
        for uv in ([0, 0], [223, 0], [111.5, 111.5], [50, 200]):
            np.testing.assert_allclose(_crop_point(m, uv) - [200, 150],
                                       rot @ (_crop_point(upright, uv) - [200, 150]),
                                       atol=1e-9)
    # the crop holds every point, the wrist in its lower half
    inv = np.linalg.inv(np.r_[upright, [[0, 0, 1]]])[:2]
    uv = (hand + [200, 150]) @ inv[:, :2].T + inv[:, 2]
    assert uv.min() > 0 and uv.max() < 223 and uv[0, 1] > 111.5 > uv[9, 1]
    with pytest.raises(ValueError, match="21"):
        hand_roi_transform(hand[:20])


def test_no_hand_on_a_face_or_a_blank_frame(models, face):  # noqa: F811
    img, _ = face
    tracker = HandTracker()
    assert tracker.track(scene(img), detect=True) == []
    assert tracker.track(np.full((360, 640, 3), 128, np.uint8), detect=True) == []
    assert tracker.hands == []
    # a crop over the face from made-up points: the landmark model sees no hand there
    points, presence = hand_landmarks(
        scene(img), np.c_[np.linspace(100, 170, 21), np.linspace(230, 90, 21)])
    assert points.shape == (21, 2) and 0 <= presence < 0.5


def test_bad_options_are_refused():
    with pytest.raises(ValueError, match="channel_order"):
        HandTracker(channel_order="hsv")
    with pytest.raises(ValueError, match="max_hands"):
        HandTracker(max_hands=0)
    with pytest.raises(ValueError, match="min_presence"):
        HandTracker(min_presence=1.0)


def _hand_clip_frames(real_video_dir, numbers) -> dict:
    """Frames of WolfgangLanger_Pexels.mp4 (a hand over the mouth on 59-227) by number;
    the test skips where the clip is absent."""
    import cv2

    path = real_video_dir / "WolfgangLanger_Pexels.mp4"
    if not path.is_file():
        pytest.skip(f"{path} is absent")
    cap = cv2.VideoCapture(str(path))
    frames = {}
    for i in range(max(numbers) + 1):
        ok, frame = cap.read()
        if i in numbers:
            frames[i] = frame
    cap.release()
    return frames


@pytest.mark.real_data
def test_a_hand_over_a_real_mouth_is_found_and_followed(real_video_dir, models):  # noqa: F811
    import cv2

    frames = _hand_clip_frames(real_video_dir, (0, 100, 101, 102, 103, 104, 105))
    tracker = HandTracker(channel_order="bgr")
    assert tracker.track(frames[0]) == []               # crying, hands down
    (hand,) = tracker.track(frames[100])                # a hand over the mouth and nose
    span = hand.max(0) - hand.min(0)
    assert span.max() > 100                              # 100 px between the eyes
    for i in range(101, 106):                            # followed without the detector
        (hand,) = tracker.track(frames[i], detect=False)
    # the hand lies over the mouth (its centre at about (428, 298) on frame 105)
    hull = cv2.convexHull(hand.astype(np.float32))
    assert cv2.pointPolygonTest(hull, (428.0, 298.0), True) > -10


@pytest.mark.real_data
def test_a_hand_in_a_wide_frame_is_found_round_the_face(real_video_dir, models):  # noqa: F811
    import cv2

    from trackers.landmarks.hands import detect_palms

    frame = _hand_clip_frames(real_video_dir, (100,))[100]
    # the frame halved inside a 1920x1080 one: the hand is 60 px across
    small = cv2.resize(frame, None, fx=0.5, fy=0.5, interpolation=cv2.INTER_AREA)
    wide = cv2.copyMakeBorder(small, 540, 360, 1100, 500, cv2.BORDER_REPLICATE)
    assert detect_palms(wide, channel_order="bgr") == []
    box = (1100 + 100, 540, 1100 + 320, 540 + 180)      # round the face
    (palm,) = detect_palms(wide, channel_order="bgr", region=box)
    (whole,) = detect_palms(frame, channel_order="bgr")
    # where the whole frame's detector puts it, halved and moved into the wide frame
    np.testing.assert_allclose(palm.box, np.add(np.multiply(whole.box, 0.5), [1100, 540] * 2),
                               atol=0.1 * (whole.box[2] - whole.box[0]))
    tracker = HandTracker(channel_order="bgr")
    assert tracker.track(wide) == []
    assert len(tracker.track(wide, region=box)) == 1


def test_the_palm_region_is_checked(models):  # noqa: F811
    from trackers.landmarks._image import region_crop
    from trackers.landmarks.hands import detect_palms

    part, corner = region_crop(np.zeros((100, 200, 3)), (-5.5, 10.2, 50.1, 900))
    assert (*corner, corner[0] + part.shape[1], corner[1] + part.shape[0]) == (0, 10, 51, 100)
    with pytest.raises(ValueError, match="outside"):
        detect_palms(np.zeros((100, 200, 3), np.uint8), region=(300, 0, 400, 50))
    with pytest.raises(ValueError, match="finite"):
        detect_palms(np.zeros((100, 200, 3), np.uint8), region=(0, 0, np.nan, 50))
