"""A surface's look taken from a photograph (synth.render.appearance)."""

import numpy as np
import pytest

from synth.render import HeadPose, Light, default_camera
from synth.render.appearance import photo_appearance
from synth.render.renderer import Renderer
from tests.synth.render._meshes import plane, sphere


def _photo(h=96, w=96, seed=0):
    """A textured 'photograph': smooth colour ramps plus fine noise."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:h, 0:w]
    base = np.stack([60 + x, 80 + 0.5 * y, 120 - 0.3 * x], -1)
    return np.clip(base + rng.normal(0, 12, (h, w, 3)), 0, 255).astype(np.uint8)


@pytest.fixture(scope="module")
def ball():
    return sphere(n_lat=30, n_lon=60, radius=5.0, centre=(0.0, -2.0, -5.0))


def test_rest_frame_is_the_photograph(ball):
    photo = _photo()
    cam = default_camera(96, 96)
    look = photo_appearance(ball, photo, cam)
    res = look.renderer(ball, supersample=1).render(ball.vertices, pose=look.pose)
    diff = np.abs(res.image.astype(int) - photo)
    assert res.mask.sum() > 1000                  # the ball covers much of the frame
    assert diff.max() <= 1                        # inside and outside the face
    ss = look.renderer(ball, supersample=2).render(ball.vertices, pose=look.pose)
    assert np.abs(ss.image.astype(float) - photo).mean() < 4.0


def test_texture_is_the_photograph_divided_by_the_rest_shading(ball):
    photo = np.full((96, 96, 3), 150, np.uint8)
    look = photo_appearance(ball, photo, default_camera(96, 96))
    tex = look.texture
    # the ball's rim turns away from the light: darker at rest, so brighter in the texture
    centre, rim = tex[49, 47, 0], tex[49, 29, 0]
    assert rim > centre > 150 / 255 * 0.99
    assert np.isfinite(tex).all()


def test_moving_surface_is_relit_by_ratio():
    card = plane(n=20, size=16.0)
    photo = np.full((96, 96, 3), 150, np.uint8)
    light = Light(direction=(1.0, 0.0, 1.0))
    look = photo_appearance(card, photo, default_camera(96, 96), light=light)
    r = look.renderer(card, supersample=1)
    rest = r.render(card.vertices, pose=look.pose).image.astype(float)
    assert abs(rest[49, 48, 0] - 150) <= 1
    # the light comes from the subject's left, in front: a card turned to its left
    # faces it more squarely and brightens, turned to its right it darkens
    centre = (0.0, -2.0, 0.0)
    left = r.render(card.vertices, pose=look.head_pose(HeadPose(yaw=30.0, centre=centre)))
    right = r.render(card.vertices, pose=look.head_pose(HeadPose(yaw=-30.0, centre=centre)))
    assert left.image[49, 48, 0] > rest[49, 48, 0] + 10
    assert right.image[49, 48, 0] < rest[49, 48, 0] - 10
    # a light of another colour scales the photograph
    dim = r.render(card.vertices, pose=look.pose,
                   light=look.light_for(Light(direction=(1.0, 0.0, 1.0),
                                              colour=(0.5, 0.5, 0.5)))).image
    assert abs(int(dim[49, 48, 0]) - 75) <= 1


def test_background_behind_the_face_is_inpainted_not_the_face(ball):
    photo = np.full((96, 96, 3), 90, np.uint8)
    # a bright mark on the face only: what the face covers must not show behind it
    photo[40:56, 40:56] = 250
    look = photo_appearance(ball, photo, default_camera(96, 96))
    assert look.background[48, 48].max() < 150
    assert (look.background[2, 2] == 90).all()    # the scene itself is kept
    moved = look.renderer(ball, supersample=1).render(
        ball.vertices + [12.0, 0.0, 0.0], pose=look.pose)
    assert not moved.mask[48, 48]
    assert moved.image[48, 48].max() < 150


def test_head_pose_at_zero_motion_is_the_photographs():
    pose = HeadPose(roll=7.0, centre=(0.0, 0.0, 0.0))
    look = photo_appearance(sphere(10, 20), _photo(), default_camera(96, 96), pose=pose)
    pts = np.random.default_rng(1).normal(0, 5, (20, 3))
    from synth.render.camera import apply_pose

    np.testing.assert_allclose(apply_pose(pts, look.head_pose(HeadPose())),
                               apply_pose(pts, pose), atol=1e-12)
    assert look.head_pose(None) is look.pose


def test_output_camera_reframes_the_photograph(ball):
    photo = _photo(96, 96)
    cam = default_camera(96, 96)
    big = default_camera(192, 192)
    look = photo_appearance(ball, photo, cam, camera=big)
    res = look.renderer(ball, supersample=1).render(ball.vertices, pose=look.pose)
    assert res.image.shape == (192, 192, 3)
    # the same scene at twice the scale: a far corner of the background maps back
    assert np.abs(res.image[4, 4].astype(int) - photo[2, 2]).max() <= 20


@pytest.mark.parametrize("kwargs, match", [
    ({"photo": np.zeros((96, 96, 3))}, "uint8 RGB"),
    ({"photo": np.zeros((96, 96), np.uint8)}, "uint8 RGB"),
    ({"photo_camera": default_camera(64, 64)}, "64x64"),
    ({"photo_camera": default_camera(96, 96, kind="perspective")}, "orthographic"),
    ({"camera": default_camera(96, 96, kind="perspective")}, "orthographic"),
])
def test_bad_arguments_are_refused(kwargs, match):
    args = {"photo": _photo(), "photo_camera": default_camera(96, 96)}
    args.update(kwargs)
    photo, cam = args.pop("photo"), args.pop("photo_camera")
    with pytest.raises(ValueError, match=match):
        photo_appearance(sphere(10, 20), photo, cam, **args)


def test_renderer_background_image_must_fit_the_camera():
    ball = sphere(10, 20)
    with pytest.raises(ValueError, match=r"\(96, 96, 3\)"):
        Renderer(ball, camera=default_camera(96, 96), background=np.zeros((50, 96, 3)))
    bg = _photo()
    r = Renderer(ball, camera=default_camera(96, 96), background=bg, supersample=3)
    res = r.render(ball.vertices + [100.0, 0.0, 0.0])   # out of view: nothing covers it
    np.testing.assert_array_equal(res.image, bg)


def test_what_the_photograph_cut_off_is_mirrored_not_smeared(ball):
    from dataclasses import replace

    # rows of the photograph are distinct: a smear of the top row would be constant
    photo = np.repeat(np.repeat(np.arange(96, dtype=np.uint8)[:, None, None] * 2, 96, 1), 3, 2)
    # the photograph's camera looks low: the ball's top 20 px lie above the photograph
    cam = replace(default_camera(96, 96), look_at=(0.0, -14.0, 0.0))
    shifted = replace(cam, look_at=(0.0, -8.0, 0.0))
    look = photo_appearance(ball, photo, cam, camera=shifted)
    res = look.renderer(ball, supersample=1).render(ball.vertices, pose=look.pose)
    # 6 cm up at 4 px/cm: output row r shows photograph row r - 24
    above = res.image[5:20, 48, 0].astype(int)               # photograph rows -19 .. -5
    expected = 2 * (24 - np.arange(5, 20))                   # mirrored: rows 19 .. 5
    assert res.mask[5:20, 48].all()
    assert np.abs(above - expected).max() <= 3
    inside = res.image[28:40, 48, 0].astype(int)             # photograph rows 4 .. 15
    assert np.abs(inside - 2 * (np.arange(28, 40) - 24)).max() <= 3
