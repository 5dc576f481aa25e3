"""The one loop over a video's frames."""

import cv2
import numpy as np
import pytest

from faceanalysis.tracking import MIN_POINTS, POINT_CONTOUR, Tracks, to_head_frame, track
from tests.trackers.conftest import draw_face
from tests.trackers.landmarks.conftest import face, models, scene  # noqa: F401 (fixtures)
from trackers import layout_from_eyes


def _face_video(tmp_path, frames_lost_brow=(2, 3)):
    """Five frames of a drawn face; on ``frames_lost_brow`` its left brow vanishes."""

    eyes = ((96.0, 105.0), (159.0, 105.0))
    img, _ = draw_face(eyes=eyes)
    lay = layout_from_eyes(*eyes, (256, 256))
    blank = img.copy()
    p = lay.contours["brow_l"].points
    x0, y0 = np.floor(p.min(0)).astype(int) - 8
    x1, y1 = np.ceil(p.max(0)).astype(int) + 8
    blank[y0:y1, x0:x1] = 190                       # the left brow vanishes
    path = tmp_path / "face.avi"
    vw = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10, (256, 256))
    for i in range(5):
        f = blank if i in frames_lost_brow else img
        vw.write(cv2.cvtColor(f, cv2.COLOR_GRAY2BGR) if f.ndim == 2 else f)
    vw.release()
    return path, lay


def test_a_lost_contour_leaves_the_head_frame_and_the_other_points(tmp_path):
    path, lay = _face_video(tmp_path)
    t = track(path, layout=lay, redetect=True).table
    assert t["success"].tolist() == [1, 1, 1, 1, 1]
    lost = t.loc[2:3]
    assert lost[[f"fid_brow_{p}_l_x" for p in ("inner", "mid", "outer")]].isna().all().all()
    assert lost[["fid_brow_inner_r_x", "fid_chin_y", "head_scale"]].notna().all().all()
    np.testing.assert_allclose(t["head_x"], t.loc[0, "head_x"], atol=1.5)


def test_tracks_hold_every_frame_and_the_points_asked_for(tmp_path):
    path, lay = _face_video(tmp_path, frames_lost_brow=())
    points = ("brow_inner_l", "mouth_corner_r", "lip_lower_centre", "furrow_mid_l", "chin",
              "brow_mid_r", "brow_outer_r")
    tr = track(path, layout=lay, points=points)
    assert isinstance(tr, Tracks) and len(tr) == 5
    assert tr.points.shape == (5, len(points), 2) and tr.stretch.shape == (5, len(points))
    assert tr.success.all() and (tr.confidence > 0).all()
    # a fiducial among the points is the same number in both arrays
    np.testing.assert_array_equal(tr.points[:, 0], tr.fiducials[:, 0])
    assert tr.table.columns[:3].tolist() == ["frame", "timestamp", "success"]


def test_unknown_points_are_refused_with_the_valid_names(tmp_path):
    path, lay = _face_video(tmp_path, frames_lost_brow=())
    with pytest.raises(ValueError, match="unknown measurement points.*brow_inner_l"):
        track(path, layout=lay, points=("nose_tip",))


def test_without_redetect_a_frame_without_a_face_is_an_error_naming_the_file(tmp_path):
    path = tmp_path / "blank.png"
    cv2.imwrite(str(path), np.full((240, 320, 3), 128, np.uint8))
    with pytest.raises(ValueError, match="blank.png"):
        track(path)


def _blank_then_faces(tmp_path, blank, faces):
    """A folder of ``blank`` grey frames, then ``faces`` frames of a rendered smile; and
    the rendered video itself."""
    from synth.render.sequence import render_sequence

    files = render_sequence(tmp_path / "seq", expression="happiness", frames=faces,
                            size=256, seed=5, flow=False)
    cap = cv2.VideoCapture(str(files["video"]))
    shown = [cap.read()[1] for _ in range(faces)]
    folder = tmp_path / "frames"
    folder.mkdir()
    for i, f in enumerate([np.full_like(shown[0], 128)] * blank + shown):
        cv2.imwrite(str(folder / f"{i:03d}.png"), f)
    return folder, files["video"]


@pytest.mark.parametrize("redetect", [False, True])
def test_frames_before_the_first_face_are_lost(tmp_path, redetect):
    folder, _ = _blank_then_faces(tmp_path, 2, 2)
    tr = track(folder, redetect=redetect, tracker="snakes")
    assert tr.success.tolist() == [False, False, True, True]


def test_with_redetect_frames_without_a_face_are_lost_and_the_face_is_found_again(tmp_path):
    folder, _ = _blank_then_faces(tmp_path, 2, 3)
    tr = track(folder, redetect=True, tracker="snakes")
    assert tr.success.tolist() == [False, False, True, True, True]
    assert np.isnan(tr.heads[:2]).all() and np.isfinite(tr.heads[2:]).all()


def test_to_head_frame_removes_translation_rotation_and_scale():
    head = np.array([10.0, 20.0, 2.0, np.pi / 2])
    np.testing.assert_allclose(to_head_frame([[10.0, 24.0]], head), [[2.0, 0.0]], atol=1e-12)


def test_every_point_names_its_contour():
    assert len(POINT_CONTOUR) >= MIN_POINTS


@pytest.fixture(scope="module")
def rendered_face():
    from trackers.landmarks import ensure_models

    try:
        ensure_models()
    except (RuntimeError, FileNotFoundError) as exc:
        pytest.skip(f"the MediaPipe face models cannot be obtained here: {exc}")
    from synth.render.sequence import synthesize

    return synthesize(frames=1, size=192, seed=3, flow=False, texture_size=256,
                      supersample=1).images[0]


def _fade_in(image, levels):
    return np.stack([np.clip(image * k + 0.5, 0, 255).astype(np.uint8) for k in levels])


def test_a_video_that_fades_in_is_tracked_from_where_its_light_settles(rendered_face):
    # the first frame with a face is placed on and judged against: a dark one held the
    # fade's lost the whole video (the contours' edges all "deepened" after it)
    levels = [0.15, 0.3, 0.5, 0.75, 1.0, 1.0, 1.0, 1.0]
    frames = _fade_in(rendered_face.astype(np.float32), levels)
    tr = track(frames, fps=10, tracker="landmarks")
    assert tr.lost_reasons[:4] == ["fading"] * 4
    assert tr.success.tolist() == [False] * 4 + [True] * 4
    # from there on, as the video from that frame
    settled = track(frames[4:], fps=10, tracker="landmarks")
    np.testing.assert_array_equal(tr.fiducials[4:], settled.fiducials)
    np.testing.assert_array_equal(tr.heads[4:], settled.heads)


def test_photographs_under_other_light_are_not_a_fade(tmp_path, rendered_face):
    # a folder of photographs is not a video in time: the second, brighter, is not held
    folder = tmp_path / "photos"
    folder.mkdir()
    for i, img in enumerate(_fade_in(rendered_face.astype(np.float32), [0.8, 1.0])):
        cv2.imwrite(str(folder / f"{i}.png"), cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
    tr = track(folder, fps=1, tracker="landmarks")
    assert "fading" not in tr.lost_reasons and tr.success[0]


def test_the_tracker_is_told_a_video_from_photographs(tmp_path, rendered_face,
                                                                   monkeypatch):
    # a video's light changes in time (a fade's end, a camera's exposure); a folder of
    # photographs may each be lit from elsewhere (a side light is no uniform change)
    from faceanalysis import tracking

    made = []
    real = tracking._anchored
    monkeypatch.setattr(tracking, "_anchored",
                        lambda *a, **k: made.append(k) or real(*a, **k))
    frames = np.stack([rendered_face] * 2)
    track(frames, fps=10, tracker="landmarks")
    folder = tmp_path / "photos"
    folder.mkdir()
    for i, img in enumerate(frames):
        cv2.imwrite(str(folder / f"{i}.png"), cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
    track(folder, fps=1, tracker="landmarks")
    assert [k["video"] for k in made] == [True, False]


def test_landmark_tracker_starts_on_the_first_face_and_loses_frames_without_one(
        tmp_path, rendered_face):
    folder = tmp_path / "frames"
    folder.mkdir()
    blank = np.full_like(rendered_face, 120)
    for i, img in enumerate([blank, blank, rendered_face, rendered_face, blank,
                             rendered_face]):
        cv2.imwrite(str(folder / f"{i:03d}.png"), cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
    tr = track(folder, fps=10, tracker="landmarks")
    assert tr.tracker == "landmarks"
    assert tr.success.tolist() == [False, False, True, True, False, True]
    assert tr.lost_reasons == ["no_face", "no_face", None, None, "no_face", None]
    t = tr.table
    assert t.loc[[0, 1, 4], ["head_x", "head_pitch", "fid_chin_x"]].isna().all().all()
    assert t.loc[[2, 3, 5], ["head_pitch", "head_yaw"]].abs().max().max() < 3.0
    assert (tr.confidence[[2, 3, 5]] > 0.3).all() and (tr.confidence[[0, 1, 4]] == 0).all()
    # the mesh's 468 points for the estimators that read more than the fiducials
    assert [m is None for m in tr.landmarks] == [True, True, False, False, True, False]
    assert tr.landmarks[2].shape == (468, 3) and tr.landmarks[2].dtype == np.float32
    np.testing.assert_allclose(tr.landmarks[2][61, :2], tr.landmarks[3][61, :2], atol=1.0)


def test_reading_landmarks_a_frame_ahead_changes_no_result(tmp_path, rendered_face,
                                                           monkeypatch):
    from faceanalysis.tracking import _anchored

    folder = tmp_path / "frames"
    folder.mkdir()
    frames = [np.roll(rendered_face, (k % 3, -k), axis=(0, 1)) for k in range(5)]
    frames[2] = np.full_like(rendered_face, 120)
    for i, img in enumerate(frames):
        cv2.imwrite(str(folder / f"{i:03d}.png"), cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
    ahead = track(folder, fps=10, tracker="landmarks", tracker_options={"prefetch": True})
    alone = track(folder, fps=10, tracker="landmarks", tracker_options={"prefetch": False})
    assert ahead.success.tolist() == alone.success.tolist() == [True, True, False, True, True]
    np.testing.assert_array_equal(ahead.fiducials, alone.fiducials)
    np.testing.assert_array_equal(ahead.pose, alone.pose)
    assert ahead.timings["cpu_s"] > 0 and ahead.timings["track_s"] > 0
    # a batch worker given one core reads them on its own thread; two cores: ahead
    monkeypatch.setenv("FACEANALYSIS_WORKER_THREADS", "1")
    assert not _anchored("numpy", None, None).prefetch
    assert _anchored("numpy", None, {"prefetch": True}).prefetch
    monkeypatch.setenv("FACEANALYSIS_WORKER_THREADS", "2")
    assert _anchored("numpy", None, None).prefetch


def test_a_video_tracked_mirrored_gives_the_same_face_mirrored(tmp_path, rendered_face):
    from faceanalysis.estimation.identifiability import mirror_partner
    from faceanalysis.io.table import FIDUCIALS

    folder = tmp_path / "frames"
    folder.mkdir()
    for k in range(4):
        img = np.roll(rendered_face, (k % 3, -k), axis=(0, 1))
        cv2.imwrite(str(folder / f"{k:03d}.png"), cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
    given = track(folder, fps=10, tracker="landmarks")
    mirrored = track(folder, fps=10, tracker="landmarks", mirror=True)
    assert not given.mirrored and mirrored.mirrored
    assert given.success.all() and mirrored.success.all()
    # the mirrored face's left brow is the subject's right, x from the other edge
    back = mirrored.fiducials[:, [FIDUCIALS.index(mirror_partner(n)) for n in FIDUCIALS]]
    back[..., 0] = rendered_face.shape[1] - 1 - back[..., 0]
    err = np.hypot(*(back - given.fiducials).transpose(2, 0, 1))
    assert err.max() < 2.5 and np.median(err) < 1.0, err


def test_tracker_choice_is_checked(tmp_path):
    path, lay = _face_video(tmp_path, frames_lost_brow=())
    with pytest.raises(ValueError, match="unknown tracker 'mesh'; choose from landmarks, "):
        track(path, tracker="mesh")
    with pytest.raises(ValueError, match="layout"):
        track(path, layout=lay, tracker="landmarks")
    assert track(path, layout=lay).tracker == "snakes"


def test_an_eyeless_face_box_must_hold_its_place_before_the_snakes_start(tmp_path,
                                                                         monkeypatch):
    # the face cascade fires on sky and title cards; without eyes found in the box, the
    # first face is trusted only after START_FRAMES frames at the same place
    import faceanalysis.tracking as tracking

    n = tracking.START_FRAMES
    folder, video = _blank_then_faces(tmp_path, n, 7)
    real = tracking._detect

    def eyeless(image, index, video):
        lay = real(image, index, video)
        lay.meta["placement"] = "face box"
        return lay

    monkeypatch.setattr(tracking, "_detect", eyeless)
    # a video that starts with the face starts at once
    assert track(video, tracker="snakes").success.all()
    # after START_FRAMES frames without a face, the eyeless box must hold for as many
    tr = track(folder, tracker="snakes")
    assert tr.success.tolist() == [False] * (2 * n - 1) + [True] * (7 - n + 1)
    assert tracking._box_overlap((0, 0, 10, 10), (5, 0, 10, 10)) == pytest.approx(1 / 3)


def test_a_lost_frame_says_why():
    from types import SimpleNamespace

    from faceanalysis.io.report import LOST_REASONS
    from faceanalysis.tracking import _lost_reason, lost_reason_counts

    hand = SimpleNamespace(extra={"hands": [np.zeros((21, 2))]})
    bare = SimpleNamespace(extra={"hands": []})
    reasons = [_lost_reason(False, None), _lost_reason(True, None), _lost_reason(True, hand),
               _lost_reason(True, bare), _lost_reason(True, SimpleNamespace(extra={})),
               _lost_reason(True, None, others=1)]
    assert reasons == ["undecodable", "no_face", "hand", "contours", "contours", "other_face"]
    assert set(reasons) <= set(LOST_REASONS)
    assert lost_reason_counts([None, *reasons]) == {"undecodable": 1, "no_face": 1,
                                                    "other_face": 1, "hand": 1, "contours": 2}
    # tracks made elsewhere do not know why
    tr = Tracks(video="v", input={}, frames=np.arange(2), timestamps=np.zeros(2),
                success=np.array([True, False]), confidence=np.ones(2),
                heads=np.zeros((2, 4)), fiducials=np.zeros((2, 11, 2)), point_names=(),
                points=np.zeros((2, 0, 2)), stretch=np.zeros((2, 0)), contours=[None, None])
    assert tr.lost_reasons == [None, None] and lost_reason_counts(tr.lost_reasons) == {}


def test_find_face_refuses_a_bad_frame_budget(tmp_path):
    from faceanalysis.tracking import find_face

    for bad in (0, -1, 2.5, True):
        with pytest.raises(ValueError, match="max_frames"):
            find_face(tmp_path / "missing.mp4", max_frames=bad)


def test_no_face_with_opencv_s_reader_names_the_full_range_detector(tmp_path):
    import cv2

    from faceanalysis.tracking import track
    from tests.faceanalysis._photos import models_or_skip
    from trackers.landmarks.runtime import litert_available

    models_or_skip()
    for i in range(2):
        cv2.imwrite(str(tmp_path / f"{i}.png"), np.full((120, 160, 3), 90, np.uint8))
    with pytest.raises(ValueError, match="no face found in any of the 2 frames") as exc:
        track(tmp_path, tracker_options={"runtime": "opencv"})
    assert "full-range detector" in str(exc.value)
    if litert_available():          # which looked, and found none
        with pytest.raises(ValueError, match="no face found") as exc:
            track(tmp_path)
        assert "full-range" not in str(exc.value)


class _HandAt:
    """An anchored tracker that reports a hand on frame ``at`` covering ``covered``, as
    the real one does where its hand detector finds one over those contours."""

    def __init__(self, inner, at: int, covered):
        self.inner, self.at, self.covered, self.n = inner, at, set(covered), 0
        self.landmarks = inner.landmarks

    def track(self, image, next_frame=None):
        from dataclasses import replace

        res = self.inner.track(image, next_frame=next_frame)
        i, self.n = self.n, self.n + 1
        if res is not None and i == self.at:
            quality = {n: replace(q, lost=True) if n in self.covered else q
                       for n, q in res.quality.items()}
            res = replace(res, quality=quality,
                          extra={**res.extra, "hands": [np.zeros((21, 2))],
                                 "occluded": tuple(sorted(self.covered))})
        return res

    def close(self):
        self.inner.close()


class _HandOver(_HandAt):
    """:class:`_HandAt` with the hand on every frame."""

    def track(self, image, next_frame=None):
        self.at = self.n
        return super().track(image, next_frame=next_frame)


def test_a_face_under_a_hand_on_every_frame_is_reported_as_such(tmp_path, rendered_face,
                                                                 monkeypatch):
    # the face is found on every frame and lost under the hand: "no face found" would send
    # the user looking for a detector problem
    from faceanalysis import tracking

    folder = tmp_path / "frames"
    folder.mkdir()
    for i in range(3):
        cv2.imwrite(str(folder / f"{i:03d}.png"), cv2.cvtColor(rendered_face, cv2.COLOR_RGB2BGR))
    real = tracking._anchored
    lower = ("upper_lip", "lower_lip", "chin_boss", "furrow_l", "furrow_r")
    monkeypatch.setattr(tracking, "_anchored",
                        lambda *a, **k: _HandOver(real(*a, **k), at=0, covered=lower))
    with pytest.raises(ValueError, match=r"frames: the face was lost in every one of the 3 "
                                         r"frames \(3 under a hand\); nothing to analyse"):
        track(folder, fps=10, tracker="landmarks")


@pytest.mark.parametrize("covered", [("upper_lip", "lower_lip", "chin_boss", "furrow_l",
                                      "furrow_r"), ("chin_boss",)])
def test_the_frames_before_a_hand_is_found_lose_what_it_covers(tmp_path, rendered_face,
                                                               monkeypatch, covered):
    # a hand arrives fingers first: the palm detector finds it a frame or two late, and
    # the frames before it read the fingers as the face's motion
    from faceanalysis import tracking
    from faceanalysis.tracking import HAND_LEAD

    folder = tmp_path / "frames"
    folder.mkdir()
    for i in range(7):
        cv2.imwrite(str(folder / f"{i:03d}.png"), cv2.cvtColor(rendered_face, cv2.COLOR_RGB2BGR))
    real = tracking._anchored
    monkeypatch.setattr(tracking, "_anchored",
                        lambda *a, **k: _HandAt(real(*a, **k), at=5, covered=covered))
    overlay = tmp_path / "overlay.mp4"
    tr = track(folder, fps=10, tracker="landmarks", overlay=overlay)
    before = list(range(5 - HAND_LEAD, 5))
    chin = tr.table["fid_chin_x"]
    if len(covered) > 1:             # the lower face: too few points left, the frames go
        assert tr.success.tolist() == [i not in (*before, 5) for i in range(7)]
        assert [tr.lost_reasons[i] for i in (*before, 5)] == ["hand"] * (HAND_LEAD + 1)
        assert all(tr.landmarks[i] is None for i in before)
    else:                            # the chin alone: its point goes, the frames stay
        assert tr.success.all()
        assert chin[[*before, 5]].isna().all()
        assert tr.table.loc[before, "fid_mouth_corner_l_x"].notna().all()
    untouched = [i for i in range(7) if i not in (*before, 5)]
    assert chin[untouched].notna().all() and tr.success[untouched].all()
    cap = cv2.VideoCapture(str(overlay))
    assert int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) == 7          # held-back frames all drawn


def test_a_subject_who_leaves_beside_someone_else_is_lost_not_replaced(face):  # noqa: F811
    # an interview: the followed (larger) face leaves the picture for a while, the other
    # stays; its frames are not measured on the other face against the subject's neutral
    from faceanalysis.io.video import Frames

    img, _ = face
    frames = [scene(img)] * 4 + [scene(img, big=False)] * 4 + [scene(img)] * 4
    tr = track(Frames(np.stack(frames), 30))
    assert tr.success.tolist() == [True] * 4 + [False] * 4 + [True] * 4
    assert tr.lost_reasons[4:8] == ["other_face"] * 4
    assert (tr.heads[tr.success, 0] < 320).all()


def test_tracks_print_as_a_summary_whatever_their_length():
    # a notebook shows the tracks: each frame's contours and landmarks must not be printed
    def tracks(n, lost):
        success = np.ones(n, bool)
        success[list(lost)] = False
        reasons = [("hand" if i % 2 else "no_face") if i in lost else None for i in range(n)]
        contour = {"brow_l": np.zeros((40, 2))}
        return Tracks(video="/data/clips/smile.mp4", input={"path": "/data/clips/smile.mp4"},
                      frames=np.arange(n), timestamps=np.zeros(n), success=success,
                      confidence=np.ones(n), heads=np.zeros((n, 4)),
                      fiducials=np.zeros((n, 11, 2)), point_names=(),
                      points=np.zeros((n, 0, 2)), stretch=np.zeros((n, 0)),
                      contours=[contour] * n, tracker="landmarks",
                      landmarks=[np.zeros((468, 3), np.float32)] * n, lost_reasons=reasons)

    short, long = repr(tracks(3, {1})), repr(tracks(3000, {1, 2, 3}))
    assert short == ("<Tracks of smile.mp4: 3 frames, 2 tracked, 1 lost (1 under a hand); "
                     "landmarks tracker>")
    # the reasons in the order analysis.json and the closing line give them
    assert long == ("<Tracks of smile.mp4: 3000 frames, 2997 tracked, 3 lost (1 without a face, "
                    "2 under a hand); landmarks tracker>")
