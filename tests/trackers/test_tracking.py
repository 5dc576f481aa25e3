import numpy as np
import pytest

from tests.trackers.conftest import draw_face
from trackers import FIDUCIAL_NAMES, Tracker, factorization_count, layout_from_eyes

EYES = ((96.0, 105.0), (159.0, 105.0))


def _err(result, truth):
    return {n: float(np.hypot(*(np.asarray(result.fiducials[n]) - t))) for n, t in truth.items()}


def test_tracks_a_moving_face_with_sub_pixel_brows():
    lay = layout_from_eyes(*EYES, (256, 256))
    before = factorization_count()
    tr = Tracker(lay)
    assert factorization_count() == before + 1
    rng = np.random.default_rng(3)
    for k in range(10):
        eyes = ((96.0 + k, 105.0 + 0.5 * k), (159.0 + k, 105.0 + 0.5 * k))
        img, truth = draw_face(eyes=eyes, brow_raise=0.01 * k, jaw=0.01 * k, noise=4, rng=rng)
        r = tr.track(img)
        assert r.index == k
        assert r.success and r.confidence > 0.5
        assert tuple(r.fiducials) == FIDUCIAL_NAMES
        e = _err(r, truth)
        assert np.mean(list(e.values())) < 1.5, (k, e)
        for n in ("brow_inner_l", "brow_inner_r", "brow_outer_l", "brow_outer_r", "chin"):
            assert e[n] < 1.0, (k, n, e[n])
        # the head frame follows the translation
        assert r.head.x == pytest.approx(127.5 + k, abs=1.5)
    assert factorization_count() == before + 1  # one factorisation for the whole sequence


def test_each_frame_starts_from_previous_equilibrium():
    lay = layout_from_eyes(*EYES, (256, 256))
    img, _ = draw_face()
    tr = Tracker(lay)
    first = tr.track(img)
    again = tr.track(img)
    assert again.iterations < first.iterations / 5
    for n in first.contours:
        np.testing.assert_allclose(again.contours[n], first.contours[n], atol=0.3)


def test_lost_contour_is_reinitialised_from_layout():
    lay = layout_from_eyes(*EYES, (256, 256))
    tr = Tracker(lay)
    img, _ = draw_face()
    tr.track(img)
    # the brows vanish: the brow contours are lost, re-initialised, still lost
    blank = img.copy()
    for side in ("l", "r"):
        p = lay.contours[f"brow_{side}"].points
        x0, y0 = np.floor(p.min(0)).astype(int) - 8
        x1, y1 = np.ceil(p.max(0)).astype(int) + 8
        blank[y0:y1, x0:x1] = 190
    r = tr.track(blank)
    assert r.quality["brow_l"].lost and r.quality["brow_r"].lost
    assert r.quality["brow_l"].reinitialised
    assert not r.success
    assert not r.quality["upper_lip"].lost
    np.testing.assert_allclose(r.contours["brow_l"].mean(0),
                               lay.contours["brow_l"].points.mean(0), atol=3.0)
    # they come back when the brows do
    r = tr.track(img)
    assert not r.quality["brow_l"].lost and not r.quality["brow_r"].lost


def test_bad_frames_name_the_frame():
    lay = layout_from_eyes(*EYES, (256, 256))
    tr = Tracker(lay)
    img, _ = draw_face()
    tr.track(img)
    with pytest.raises(ValueError, match="frame 1 is 200x256"):
        tr.track(np.zeros((256, 200), np.uint8))
    bad = img.astype(np.float32) / 255
    bad[150, 128] = np.nan
    with pytest.raises(ValueError, match="frame 1: .*NaN"):
        tr.track(bad)
    with pytest.raises(ValueError, match="strength"):
        Tracker(lay, strength="fast")
    with pytest.raises(ValueError, match="FaceLayout"):
        Tracker({"brow_l": np.zeros((3, 2))})


def test_paper_strength_also_tracks():
    lay = layout_from_eyes(*EYES, (256, 256))
    img, truth = draw_face()
    r = Tracker(lay, strength="paper", first_max_iter=4000).track(img)
    e = _err(r, truth)
    assert e["brow_inner_l"] < 1.5 and e["chin"] < 1.0


@pytest.mark.real_data
def test_real_video_tracks_without_crashing(real_video_dir):
    import cv2

    from trackers import detect_layout

    path = sorted(real_video_dir.glob("*.mp4"))[0]
    cap = cv2.VideoCapture(str(path))
    frames = []
    while len(frames) < 15:
        ok, f = cap.read()
        if not ok:
            break
        frames.append(f)
    cap.release()
    if len(frames) < 2:
        pytest.skip(f"cannot decode {path.name}")
    tr = Tracker(detect_layout(frames[0], channel_order="bgr"), channel_order="bgr")
    for f in frames:
        r = tr.track(f)
        assert all(np.isfinite(p).all() for p in r.contours.values())
        assert np.isfinite(list(r.fiducials.values())).all()


def test_brow_mid_fraction_option():
    lay = layout_from_eyes(*EYES, (256, 256))
    img, _ = draw_face()
    r = Tracker(lay, brow_mid=0.0).track(img)
    np.testing.assert_allclose(r.fiducials["brow_mid_l"], r.fiducials["brow_inner_l"])
    with pytest.raises(ValueError, match="brow_mid"):
        Tracker(lay, brow_mid=2.0)
