"""Skin texture on the real face mesh: features where the fiducials are, per-identity looks."""

import numpy as np
import pytest

from synth.mesh import generate_face_mesh
from synth.render.groundtruth import head_frame, project_landmarks
from synth.render.renderer import Renderer
from synth.render.shading import Light
from synth.render.texture import paint_skin_texture, texture_params


@pytest.fixture(scope="module")
def mesh():
    return generate_face_mesh()


def _frontal(mesh, seed, **kw):
    r = Renderer(mesh, texture=paint_skin_texture(mesh, seed), supersample=2, grey=True, **kw)
    res = r.render(mesh.vertices)
    return res, project_landmarks(mesh.landmark_positions(), r, res)


def _dark_centre(profile):
    base = np.median(np.concatenate([profile[:3], profile[-3:]]))
    w = np.clip(base - profile, 0, None)
    w[w < 0.3 * w.max()] = 0
    return (w * np.arange(len(profile))).sum() / w.sum(), base


@pytest.mark.parametrize("seed", [0, 3, 11])
def test_brow_fiducials_lie_on_the_dark_brow_band(mesh, seed):
    import cv2

    res, pts = _frontal(mesh, seed)
    img = res.image.astype(np.float32)
    for name in ("brow_inner_l", "brow_mid_l", "brow_outer_l", "brow_inner_r", "brow_mid_r",
                 "brow_outer_r"):
        x, y, visible = pts[name]
        assert visible
        c, r = int(round(x)), int(round(y))
        prof = img[r - 8:r + 9, c]
        centre, base = _dark_centre(prof)
        at = cv2.getRectSubPix(img, (1, 1), (x, y))[0, 0]
        assert at < 0.6 * base, name                                # on dark brow texture
        if "outer" not in name:
            # inside the band (not at its round tip): the centre line passes through the
            # fiducial and its whole neighbourhood is dark
            assert abs(centre - 8 - (y - r)) < 1.0, name
            assert img[r - 1:r + 2, c - 1:c + 2].mean() < 0.6 * base, name


def test_mouth_corners_furrows_and_chin(mesh):
    res, pts = _frontal(mesh, 3, light=Light(ambient=1.0, specular_scale=0.0))
    img = res.image.astype(float)
    for side, out in (("l", 1), ("r", -1)):
        x, y, _ = pts[f"mouth_corner_{side}"]
        c, r = int(round(x)), int(round(y))
        cheek = img[r, c + out * 8]
        assert img[r, c] < 0.75 * cheek                       # dark commissure vs cheek
        assert img[r, c - out * 4] < 0.85 * cheek             # lips inside the corner
        x, y, _ = pts[f"furrow_top_{side}"]
        c, r = int(round(x)), int(round(y))
        row = img[r + 2, c - 6:c + 7]
        assert row.min() < 0.85 * np.median(row)              # furrow line just below its top
    # chin boss: the painted outline is symmetric about the chin fiducial
    x, y, _ = pts["chin"]
    c, r = int(round(x)), int(round(y))
    row = img[r, c - 25:c + 26]
    left = np.argmin(row[:25])
    right = 26 + np.argmin(row[26:])
    assert abs((left + right) / 2 - 25 - (x - c)) <= 1.0
    col = img[r - 15:r + 16, c]
    assert col.min() < 0.9 * np.median(col)


def test_hair_above_the_hairline(mesh):
    res, pts = _frontal(mesh, 5)
    img = res.image.astype(float)
    for name in ("hairline_centre", "hairline_l", "hairline_r"):
        x, y, _ = pts[name]
        c, r = int(round(x)), int(round(y))
        assert img[r - 5, c] < 0.6 * img[r + 5, c], name
    # head frame: origin on the midline below the hairline's top, roll 0, scale reaching
    # down to the nostrils (as trackers.fiducials.head_frame measures it on contours)
    hf = head_frame(mesh, res.camera, res.pose)
    assert hf["head_x"] == pytest.approx(127.5, abs=0.05) and hf["head_roll"] == 0.0
    x, y, _ = pts["hairline_centre"]
    assert y < hf["head_y"] < pts["brow_mid_l"][1]
    nose_y = hf["head_y"] + hf["head_scale"]
    assert pts["nose_tip"][1] < nose_y < pts["lip_upper_centre"][1]
    assert hf["px_per_cm"] == pytest.approx(res.camera.scale)


def test_head_frame_follows_the_rigid_head(mesh):
    from synth.render.camera import HeadPose, default_camera

    cam = default_camera(256, 256)
    a = head_frame(mesh, cam)
    b = head_frame(mesh, cam, HeadPose(roll=10.0, translation=(1.0, 0.0, 0.0)))
    assert b["head_roll"] == pytest.approx(np.radians(10.0))
    assert b["head_scale"] == pytest.approx(a["head_scale"])
    assert b["head_x"] > a["head_x"]
    c = head_frame(mesh, default_camera(512, 512))
    assert c["head_scale"] == pytest.approx(2 * a["head_scale"], rel=1e-3)


def test_texture_is_deterministic_and_varies_per_identity(mesh):
    a = paint_skin_texture(mesh, 4, size=256)
    b = paint_skin_texture(mesh, 4, size=256)
    c = paint_skin_texture(mesh, 5, size=256)
    assert np.array_equal(a, b)
    assert not a.flags.writeable
    assert np.abs(a - c).mean() > 0.01
    assert texture_params(4) != texture_params(5)
    with pytest.raises(ValueError, match="seed"):
        texture_params(-1)
    with pytest.raises(ValueError, match="size"):
        paint_skin_texture(mesh, 1, size=10)


def test_skin_has_fine_non_repeating_detail(mesh):
    tex = paint_skin_texture(mesh, 2).mean(axis=2)
    patch = tex[500:628, 400:528]                              # cheek/nose skin
    hp = patch - np.asarray(__import__("cv2").GaussianBlur(patch, (0, 0), 4))
    assert hp.std() > 0.01
    # no periodicity: the autocorrelation has no secondary peak near the main one
    f = np.fft.fft2(hp - hp.mean())
    ac = np.real(np.fft.ifft2(f * np.conj(f)))
    ac /= ac[0, 0]
    ac[:3, :3] = ac[-3:, -3:] = ac[:3, -3:] = ac[-3:, :3] = 0
    assert ac.max() < 0.3
