import numpy as np
import pytest

from tests.trackers.landmarks.conftest import far_scene, scene
from trackers.landmarks import LandmarkTracker
from trackers.landmarks.runtime import litert_available


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


def test_a_face_upside_down_is_read_upside_down(face, monkeypatch):
    """The detector places its keypoints as on an upright face; the tracker looks at the
    picture turned too, and reads an upside-down face from a crop turned its way."""
    import trackers.landmarks.tracker as tracker_module

    img, corners = face
    turned = np.ascontiguousarray(img[::-1, ::-1])
    truth = (np.array(img.shape[1::-1]) - 1) - corners       # the corners, turned
    def read(tracker):
        lm = [tracker.track(turned) for _ in range(3)][-1]
        if lm is None:
            return None, np.inf
        iod = np.linalg.norm(lm.points[263] - lm.points[33])
        return lm, np.linalg.norm(lm.points[[61, 291]] - truth, axis=1).max() / iod

    lm, error = read(LandmarkTracker())
    assert lm.presence > 0.9 and error < 0.1
    # the subject's left eye (263) on the image's left, as on a face upside down
    assert lm.points[263, 0] < lm.points[33, 0]
    # read from the detector's keypoints as they come, the crop is turned the wrong way:
    # the mesh lands on other features, or the face is lost
    monkeypatch.setattr(tracker_module, "_upright", lambda net, image, face, *a: (face, None))
    assert read(LandmarkTracker())[1] > 0.5


def test_a_point_picks_the_face_to_follow_instead_of_the_largest(face):
    img, _ = face
    two = scene(img)                  # the larger face at the left, a smaller one at 480, 160
    assert _centre(LandmarkTracker().track(two)) < 320
    tracker = LandmarkTracker(start_near=(480, 160))
    assert [_centre(tracker.track(two)) > 320 for _ in range(3)] == [True] * 3
    # lost for long, then back: the point still says which
    for _ in range(40):
        assert tracker.track(np.full_like(two, 128)) is None
    assert _centre(tracker.track(two)) > 320
    for bad in ((1, np.nan), (1, 2, 3), "here"):
        with pytest.raises(ValueError, match="start_near must be a point"):
            LandmarkTracker(start_near=bad)


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


def test_where_several_faces_were_seen_a_lost_face_is_not_replaced_by_another(face):
    from trackers.landmarks.tracker import _MEMORY

    img, _ = face
    tracker = LandmarkTracker()
    assert _centre(tracker.track(scene(img))) < 320 and tracker.others == 0
    # the followed face leaves; the other stays: someone else's, for as long as it is lost
    for _ in range(_MEMORY + 5):
        assert tracker.track(scene(img, big=False)) is None and tracker.others == 1
    back = tracker.track(scene(img))
    assert back.detected and _centre(back) < 320 and tracker.others == 0
    # a face alone in the picture is the same face wherever it comes back
    alone = LandmarkTracker()
    assert _centre(alone.track(scene(img, small=False))) < 320
    moved = alone.track(scene(img, big=False))
    assert moved is not None and _centre(moved) > 320 and alone.others == 0


@pytest.mark.parametrize("recrop", [None, np.inf])
def test_a_face_that_jumps_is_read_from_a_crop_that_fits_it(face, recrop):
    img, _ = face

    def frame(dx, dy):
        canvas = np.full((360, 640, 3), img[0, 0], np.uint8)
        canvas[60 + dy:252 + dy, 200 + dx:392 + dx] = img
        return canvas

    tracker = LandmarkTracker() if recrop is None else LandmarkTracker(recrop=recrop)
    for _ in range(3):
        still = tracker.track(frame(0, 0))
    # the face jumps 40 px left and 20 px down between two frames: read from the last
    # frame's crop, its landmarks land a median 6 px from the moved face's
    jumped = tracker.track(frame(-40, 20))
    err = np.median(np.hypot(*(jumped.points - still.points - [-40, 20]).T))
    if recrop is None:
        assert err < 1.5
    else:
        assert err > 3.0


def test_settle_gives_where_tracking_a_still_frame_converges(face):
    img, _ = face
    tracker = LandmarkTracker()
    assert tracker.settle(img) is None                      # nothing tracked yet
    first = tracker.track(img)
    settled = tracker.settle(img)
    assert not settled.detected and settled.presence > 0.9
    later = [tracker.track(img) for _ in range(3)]
    off = np.median(np.hypot(*(first.points - later[-1].points).T))
    for lm in later:
        # the render's tracking frames alternate by about 0.12 px around where they settle
        assert np.median(np.hypot(*(lm.points - settled.points).T)) < 0.2
    assert off > 0.2          # the detection frame's own landmarks lie farther off


def _same(a, b):
    if a is None or b is None:
        return a is b
    return (np.array_equal(a.points, b.points) and np.array_equal(a.z, b.z)
            and a.presence == b.presence and a.detected == b.detected)


def test_a_prefetched_frame_gives_what_tracking_it_gives(face):
    img, _ = face
    blank = np.full_like(img, 128)
    moved = np.roll(img, (3, -5), axis=(0, 1))
    frames = [img, moved, blank, img, moved, img]
    plain = LandmarkTracker()
    expected = [plain.track(f) for f in frames]
    with LandmarkTracker() as tracker:
        got = []
        for k, f in enumerate(frames):
            got.append(tracker.track(f))
            if k + 1 < len(frames):
                tracker.prefetch(frames[k + 1])
        assert tracker._executor is not None
    assert tracker._executor is None                        # closed by the context
    assert all(_same(a, b) for a, b in zip(expected, got))
    # a prefetch that is not followed by its frame is undone: the state is as before it
    tracker = LandmarkTracker()
    first = tracker.track(img)
    tracker.prefetch(blank)                    # would lose the face...
    after = tracker.track(moved)               # ...but another frame comes instead
    reference = LandmarkTracker()
    reference.track(img)
    assert _same(after, reference.track(moved)) and not after.detected
    tracker.prefetch(moved)
    settled = tracker.settle(moved)           # settle waits for and undoes it too
    assert settled is not None and first is not None
    tracker.close()


def test_crop_change_is_in_crop_pixels(face):
    from trackers.landmarks.tracker import _crop_change

    lm = LandmarkTracker().track(face[0])
    assert _crop_change(lm.points, lm.points) == 0.0
    side = 1.5 * np.ptp(lm.points, axis=0).max()          # the crop's side, image pixels
    assert _crop_change(lm.points, lm.points + [side / 192 * 5, 0]) == pytest.approx(5.0)


@pytest.mark.skipif(not litert_available(), reason="the full-range detector needs LiteRT")
def test_a_face_far_from_the_camera_is_found_by_the_full_range_detector(face):
    img, corners = face
    far, k, offset = far_scene(img)
    assert LandmarkTracker(full_range=False, tiles=False).track(far) is None
    tracker = LandmarkTracker()
    assert tracker.full_range
    lm = tracker.track(far)
    assert lm is not None and lm.detected
    # the mesh's mouth corners (61: subject's right, 291: left) on the render's
    true = corners * k + offset
    assert np.abs(lm.points[[61, 291]] - true).max() < 0.3 * np.ptp(true[:, 0])   # mouth width
    # and tracked on the next frame without another detection
    nxt = tracker.track(far)
    assert nxt is not None and not nxt.detected


@pytest.mark.skipif(not litert_available(), reason="the full-range detector needs LiteRT")
def test_a_far_bystander_is_not_taken_for_the_face_just_lost(face):
    import cv2

    from trackers.landmarks.tracker import _MEMORY

    img, _ = face
    far, _, _ = far_scene(img)                        # a face of 80 px at the right
    both = far.copy()
    both[200:584, 100:484] = cv2.resize(img, (384, 384))   # and one of 250 px at the left
    tracker = LandmarkTracker()
    assert _centre(tracker.track(both)) < 640
    for _ in range(_MEMORY + 1):                      # the near face leaves
        assert tracker.track(far) is None
    picked = tracker.track(far)                       # forgotten: the one face there is
    assert picked is not None and _centre(picked) > 640
    # a far face lost and back is the same face: found again at once
    assert tracker.track(np.full_like(far, 128)) is None
    back = tracker.track(far)
    assert back is not None and back.detected and _centre(back) > 640


@pytest.mark.skipif(not litert_available(), reason="the full-range detector needs LiteRT")
def test_a_far_face_is_looked_at_again_by_the_short_range_detector(face):
    from trackers.landmarks.detection import FaceDetection, detect_faces
    from trackers.landmarks.models import ensure_models
    from trackers.landmarks.runtime import load_network
    from trackers.landmarks.tracker import _closer_look

    img, _ = face
    far, k, offset = far_scene(img)
    near = load_network(ensure_models()["face_detection"])
    (true,) = detect_faces(img)            # the render at its own size, moved into the frame
    box = np.add(np.multiply(true.box, k), np.tile(offset, 2))
    # a coarse detection: its box a third too large and off by a sixth of the face
    x0, y0, x1, y1 = box
    d = (x1 - x0) / 6
    coarse = FaceDetection((x0 - 2 * d, y0 - d, x1 + 2 * d, y1 + 2 * d),
                           true.keypoints * k + offset + d, 0.6)
    seen = _closer_look(near, far, coarse, "rgb", 0.5)
    # (the detector at another scale: within a tenth of the face)
    np.testing.assert_allclose(seen.box, box, atol=0.1 * (x1 - x0))
    np.testing.assert_allclose(seen.keypoints[:4], true.keypoints[:4] * k + offset,  # not ears
                               atol=0.1 * (x1 - x0))
    # where the short-range detector finds nothing round it, the detection stays as it was
    blank = np.full_like(far, 128)
    assert _closer_look(near, blank, coarse, "rgb", 0.5) is coarse


@pytest.mark.real_data
@pytest.mark.skipif(not litert_available(), reason="the full-range detector needs LiteRT")
def test_a_real_face_24_px_between_the_eyes_is_fitted_at_its_size(real_video_dir, models):
    import cv2

    from trackers.landmark_contours import interocular_distance as iod

    path = real_video_dir / "WolfgangLanger_Pexels.mp4"
    if not path.is_file():
        pytest.skip(f"{path} is absent")
    ok, frame = cv2.VideoCapture(str(path)).read()
    given = iod(LandmarkTracker(channel_order="bgr").track(frame).points)
    small = cv2.resize(frame, None, fx=0.24, fy=0.24, interpolation=cv2.INTER_AREA)
    wide = cv2.copyMakeBorder(small, 300, 1080 - 300 - small.shape[0], 900,
                              1920 - 900 - small.shape[1], cv2.BORDER_CONSTANT, value=(100,) * 3)
    lm = LandmarkTracker(channel_order="bgr").track(wide)
    # (from the full-range detector's own box the mesh settles 30 % too large)
    assert lm is not None and lm.presence > 0.9
    assert iod(lm.points) == pytest.approx(0.24 * given, rel=0.05)


def test_real_faces_upside_down_are_tracked_as_upright(real_video_dir, models):
    """The talking face, and the clip with a hand, turned by 180 degrees: each frame's
    landmarks are the upright frame's, turned (where the detector's own keypoints put the
    mesh on other features of cap13 with full confidence)."""
    import cv2

    from trackers.landmark_contours import interocular_distance as iod

    for name in ("cap13_edit2.mp4", "WolfgangLanger_Pexels.mp4"):
        path = real_video_dir / name
        if not path.is_file():
            pytest.skip(f"{path} is absent")
        capture = cv2.VideoCapture(str(path))
        frames = [capture.read()[1] for _ in range(20)]
        capture.release()
        upright, turned = LandmarkTracker(channel_order="bgr"), LandmarkTracker(channel_order="bgr")
        far_corner = np.array(frames[0].shape[1::-1]) - 1
        for frame in frames:
            a, b = upright.track(frame), turned.track(cv2.rotate(frame, cv2.ROTATE_180))
            assert b is not None and b.presence > 0.9
            assert np.abs(far_corner - b.points - a.points).max() < 0.1 * iod(a.points), name


def test_a_real_face_at_any_angle_in_the_picture_is_tracked(real_video_dir, models):
    """cap13's first frames turned in steps of 15 degrees (a subject lying down, a camera
    on its side): each turn's landmarks are the upright frame's, turned."""
    import cv2

    from trackers.landmark_contours import interocular_distance as iod

    path = real_video_dir / "cap13_edit2.mp4"
    if not path.is_file():
        pytest.skip(f"{path} is absent")
    capture = cv2.VideoCapture(str(path))
    frames = [capture.read()[1] for _ in range(3)]
    capture.release()
    h, w = frames[0].shape[:2]
    upright = [LandmarkTracker(channel_order="bgr").track(f) for f in frames][-1].points
    errors = {}
    for angle in range(15, 360, 15):
        turn = cv2.getRotationMatrix2D((w / 2, h / 2), angle, 1.0)
        turn[:, 2] += (520 - w) / 2, (520 - h) / 2
        tracker = LandmarkTracker(channel_order="bgr")
        lm = [tracker.track(cv2.warpAffine(f, turn, (520, 520), borderValue=(120,) * 3))
              for f in frames][-1]
        truth = upright @ turn[:, :2].T + turn[:, 2]
        errors[angle] = np.inf if lm is None else np.abs(lm.points - truth).max() / iod(upright)
    assert max(errors.values()) < 0.1, errors


def test_without_the_full_range_detector_a_far_face_is_found_on_tiles(face, monkeypatch):
    import trackers.landmarks.tracker as T

    img, corners = face
    far, k, offset = far_scene(img)
    tracker = LandmarkTracker(runtime="opencv")        # cannot run the full-range model
    assert not tracker.full_range and tracker.tiles
    lm = tracker.track(far)
    assert lm is not None and lm.detected
    true = corners * k + offset
    assert np.abs(lm.points[[61, 291]] - true).max() < 0.3 * np.ptp(true[:, 0])
    # while no face is found, the tiles are searched on every TILE_EVERY-th frame
    calls = []
    real = T._tiled
    monkeypatch.setattr(T, "_tiled", lambda *a: calls.append(1) or real(*a))
    blank = np.full_like(far, 128)
    searcher = LandmarkTracker(runtime="opencv")
    for _ in range(2 * T.TILE_EVERY + 1):
        assert searcher.track(blank) is None
    assert len(calls) == 3


def test_bad_settings_are_refused():
    with pytest.raises(ValueError, match="'auto', 'litert', 'opencv'"):
        LandmarkTracker(runtime="onnx")
    with pytest.raises(ValueError, match="'rgb', 'bgr'"):
        LandmarkTracker(channel_order="yuv")
    with pytest.raises(ValueError, match="recrop"):
        LandmarkTracker(recrop=0)
    with pytest.raises(ValueError, match="min_presence"):
        LandmarkTracker(min_presence=0)
    with pytest.raises(ValueError, match="LiteRT"):
        LandmarkTracker(runtime="opencv", full_range=True)
