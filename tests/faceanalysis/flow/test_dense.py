"""Face flow: OpenCV flow methods, the canonical face grid, stabilised crops, rigid motion."""

import math

import cv2
import numpy as np
import pytest

from faceanalysis.flow.dense import (
    FLOW_METHODS,
    compute_flow,
    face_flow,
    flow_to_colour,
    stabilize,
    tvl1_scales,
    video_face_flow,
)
from faceanalysis.flow.grid import (
    FaceGrid,
    grid_image_points,
    head_array,
    image_flow_to_grid,
    remove_rigid,
    rigid_basis,
    vectors_to_head,
)


def _texture(rng, h=240, w=240, sigma=1.5):
    img = rng.random((h, w)).astype(np.float32) * 255
    return np.clip(cv2.GaussianBlur(img, (0, 0), sigma) * 3 - 255, 0, 255).astype(np.uint8)


def _similarity(x, y, s, roll):
    """2x3 map from head coordinates (units) to image px for head frame (x, y, s, roll)."""
    c, sn = math.cos(roll), math.sin(roll)
    return np.array([[s * c, -s * sn, x], [s * sn, s * c, y]])


@pytest.mark.parametrize("method", FLOW_METHODS)
def test_methods_recover_a_translation(rng, method):
    a = _texture(rng, 96, 96)
    b = np.roll(np.roll(a, 2, axis=1), -1, axis=0)
    fl = compute_flow(a, b, method)
    assert fl.shape == (96, 96, 2) and fl.dtype == np.float32
    inner = fl[24:72, 24:72]
    np.testing.assert_allclose(np.median(inner.reshape(-1, 2), axis=0), [2.0, -1.0], atol=0.15)


def test_flows_calculated_in_threads_at_once_are_those_calculated_one_by_one(rng):
    from concurrent.futures import ThreadPoolExecutor

    pairs = []
    for k in range(2):
        a = _texture(rng, 300, 260)
        pairs.append((a, np.roll(a, k + 1, axis=1)))
    alone = [compute_flow(a, b) for a, b in pairs]
    with ThreadPoolExecutor(2) as pool:
        together = list(pool.map(lambda k: [compute_flow(*pairs[k]) for _ in range(20)],
                                 [0, 1]))
    for k, flows in enumerate(together):
        for fl in flows:
            np.testing.assert_array_equal(fl, alone[k])


def test_flow_inputs_are_checked(rng):
    a = _texture(rng, 64, 64)
    with pytest.raises(ValueError, match="unknown flow method"):
        compute_flow(a, a, "lk")
    with pytest.raises(ValueError, match="differ in size"):
        compute_flow(a, a[:32], "dis")
    colour = np.dstack([a, a, a])
    assert np.abs(compute_flow(colour, colour)).max() < 0.05   # colour (BGR) accepted


def test_tvl1_pyramid_is_deep_enough_but_fits_the_image():
    assert tvl1_scales((2048, 2048), 40.0) == 1 + math.ceil(math.log2(40))
    assert tvl1_scales((512, 512), 40.0) == 6                # 512 / 2**5 = 16 px
    assert tvl1_scales((32, 32), 40.0) == 2                  # coarsest level stays >= 16 px
    assert tvl1_scales((256, 256), 0.5) == 3


def test_grid_geometry_and_head_conversions():
    g = FaceGrid()
    p = g.points
    assert p.shape == (64, 48, 2)
    np.testing.assert_allclose(p[0, 0], [g.u[0], g.v[0]])
    np.testing.assert_allclose(p[-1, -1], [g.u[1], g.v[1]])
    head = (120.0, 40.0, 100.0, 0.3)
    img = grid_image_points(g, head)
    # back to head coordinates through the trackers' HeadFrame convention
    from trackers.fiducials import HeadFrame

    hf = HeadFrame(*head)
    np.testing.assert_allclose(hf.to_head(img.reshape(-1, 2)).reshape(p.shape), p, atol=1e-9)
    v = vectors_to_head(np.array([3.0, 1.0]), head)
    c, s = math.cos(0.3), math.sin(0.3)
    np.testing.assert_allclose(v, [(c * 3 + s * 1) / 100, (-s * 3 + c * 1) / 100])
    assert head_array({"head_x": 1, "head_y": 2, "head_scale": 3, "head_roll": 0}).tolist() \
        == [1, 2, 3, 0]
    with pytest.raises(ValueError, match="4 values"):
        head_array([1, 2, 3])
    with pytest.raises(ValueError, match="at least 2x2"):
        FaceGrid(rows=1)


def test_uniform_image_flow_maps_to_uniform_head_displacement():
    g = FaceGrid(rows=16, cols=12)
    head = (200.0, 60.0, 120.0, -0.2)
    flow = np.zeros((400, 400, 2), np.float32)
    flow[..., 0], flow[..., 1] = 3.0, 1.0
    d = image_flow_to_grid(flow, head, g)
    np.testing.assert_allclose(d, np.broadcast_to(vectors_to_head(np.array([3.0, 1.0]), head),
                                                  d.shape), atol=1e-6)
    # a validity mask: invalid pixels do not leak into the average
    valid = np.ones((400, 400), bool)
    flow2 = flow.copy()
    flow2[:, :200] = 50.0
    valid[:, :200] = False
    d2 = image_flow_to_grid(flow2, head, g, valid=valid)
    right = grid_image_points(g, head)[..., 0] > 215
    np.testing.assert_allclose(d2[right], d[right], atol=1e-5)


def test_stabilize_puts_the_head_frame_at_the_grid(rng):
    img = _texture(rng, 300, 300)
    g = FaceGrid(rows=20, cols=16)
    head = (150.0, 60.0, 110.0, 0.25)
    crop = stabilize(img, head, g, px_per_unit=50, pad=0.0)
    # the crop pixel of a grid point shows the image at that point's image position
    pts = grid_image_points(g, head)
    for r, c in ((3, 4), (15, 10)):
        hx, hy = g.points[r, c]
        cx = int(round((hx - g.u[0]) * 50))
        cy = int(round((hy - g.v[0]) * 50))
        x, y = pts[r, c]
        assert abs(int(crop[cy, cx]) - int(cv2.getRectSubPix(img, (1, 1), (x, y))[0, 0])) < 40


def _moving_face(rng, T=6, stabil_noise=0.0, scale=140.0):
    """Frames of a textured 'face' that moves rigidly (known head frames) and whose lower
    part is pushed down by a smooth bump that grows over time (known, in head units);
    ``scale`` px to the head unit on the first frame."""
    base = _texture(rng, 420, 420, sigma=1.2)
    g = FaceGrid(rows=24, cols=18)
    heads = []
    frames = []
    bumps = []
    # canonical image: head frame (210, 90, scale, 0)
    H0 = np.array([210.0, 90.0, scale, 0.0])
    yy, xx = np.mgrid[0:420, 0:420].astype(np.float32)
    hu = (xx - H0[0]) / H0[2]
    hv = (yy - H0[1]) / H0[2]
    for t in range(T):
        amp = 0.02 * t / (T - 1)                      # head units
        bump = amp * np.exp(-((hu - 0.1) ** 2 + (hv - 1.1) ** 2) / (2 * 0.15 ** 2))
        # deformed canonical image: content moves down by bump (backward map approx.)
        deformed = cv2.remap(base, xx, (yy - bump * H0[2]).astype(np.float32),
                             cv2.INTER_LINEAR)
        head = np.array([210 + 6 * t, 90 - 3 * t, scale * (1 + 0.02 * t), 0.03 * t])
        M = _similarity(*head) @ np.linalg.inv(np.vstack([_similarity(*H0), [0, 0, 1]]))
        frames.append(cv2.warpAffine(deformed, M, (420, 420), borderMode=cv2.BORDER_REFLECT))
        jitter = rng.normal(0, stabil_noise, 4) * [1, 1, 1, 0.01] if stabil_noise else 0
        heads.append(head + jitter)
        p = g.points
        bumps.append(np.stack([np.zeros(p.shape[:2]), amp * np.exp(
            -((p[..., 0] - 0.1) ** 2 + (p[..., 1] - 1.1) ** 2) / (2 * 0.15 ** 2))], -1))
    return frames, np.array(heads), g, np.array(bumps)


@pytest.mark.parametrize("stabilization", ["head", "flow"])
def test_face_flow_removes_head_motion_and_keeps_deformation(rng, stabilization):
    frames, heads, g, truth = _moving_face(rng)
    ff = face_flow(frames, heads, grid=g, stabilization=stabilization)
    assert ff.displacement.shape == (6, 24, 18, 2) and ff.valid.all()
    np.testing.assert_array_equal(ff.displacement[0], 0.0)
    inner = np.zeros(g.shape, bool)
    inner[3:-3, 3:-3] = True
    d = remove_rigid(ff.displacement, inner)
    t = remove_rigid(truth, inner)
    err = np.abs(d - t)[:, inner].max()
    assert err < 0.004, err                           # peak bump is 0.02 head units
    assert np.abs(t[-1, inner]).max() > 0.015


def test_flow_stabilisation_corrects_head_frame_jitter(rng):
    frames, heads, g, truth = _moving_face(rng, stabil_noise=1.5)
    inner = np.zeros(g.shape, bool)
    inner[3:-3, 3:-3] = True
    errs = {}
    for mode in ("head", "flow"):
        ff = face_flow(frames, heads, grid=g, stabilization=mode)
        errs[mode] = np.abs(ff.displacement - truth)[:, inner].mean()
    assert errs["flow"] < 0.5 * errs["head"], errs


def test_a_large_face_is_aligned_on_a_coarse_flow_as_well_as_on_the_full_one(rng, monkeypatch):
    import faceanalysis.flow.dense as dense

    # 170 px to the head unit: a crop of 267 px, aligned on the flow at a quarter of it
    frames, heads, g, truth = _moving_face(rng, stabil_noise=1.5, scale=170.0)
    inner = np.zeros(g.shape, bool)
    inner[3:-3, 3:-3] = True
    errs = {}
    for label, side in (("coarse", dense.ALIGN_MIN_SIDE), ("full", 10**6)):
        monkeypatch.setattr(dense, "ALIGN_MIN_SIDE", side)
        ff = face_flow(frames, heads, grid=g, stabilization="flow")
        assert ff.valid.all() and ff.px_per_unit == 160.0
        errs[label] = np.abs(ff.displacement - truth)[:, inner].mean()
    head = face_flow(frames, heads, grid=g, stabilization="head")
    errs["head"] = np.abs(head.displacement - truth)[:, inner].mean()
    assert errs["coarse"] < 0.5 * errs["head"], errs
    assert errs["coarse"] < 1.2 * errs["full"], errs


def test_lost_frames_and_bad_arguments(rng):
    frames, heads, g, _ = _moving_face(rng, T=3)
    heads = heads.copy()
    heads[1] = np.nan
    ff = face_flow(frames, heads, grid=g, stabilization="head")
    assert ff.valid.tolist() == [True, False, True]
    assert np.isnan(ff.displacement[1]).all()
    with pytest.raises(ValueError, match="shape"):
        face_flow(frames, heads[:2], grid=g)
    with pytest.raises(ValueError, match="reference"):
        face_flow(frames, heads, grid=g, reference=5)
    with pytest.raises(ValueError, match="stabilization"):
        face_flow(frames, np.nan_to_num(heads, nan=100.0), grid=g, stabilization="none")


def test_a_frame_without_the_face_in_view_is_lost_not_bridged(rng, tmp_path):
    # a frame the tracker lost keeps a flow bridged from the last alignment, unless the
    # face cannot be seen there (no face found, a hand over it): then it is lost
    import pandas as pd

    frames, heads, g, _ = _moving_face(rng, T=5)
    for t, im in enumerate(frames):
        cv2.imwrite(str(tmp_path / f"{t}.png"), im)
    table = pd.DataFrame(heads, columns=["head_x", "head_y", "head_scale", "head_roll"])
    table.insert(0, "frame", np.arange(5))
    table.insert(1, "success", [1, 1, 1, 0, 1])
    bridged = video_face_flow(tmp_path, table=table, grid=g)
    assert bridged.valid.tolist() == [True] * 5
    hidden = video_face_flow(tmp_path, table=table, grid=g, hidden=[3])
    assert hidden.valid.tolist() == [True, True, True, False, True]
    np.testing.assert_array_equal(hidden.displacement[4], bridged.displacement[4])


def test_rigid_basis_projection():
    g = FaceGrid(rows=10, cols=8)
    b = rigid_basis(g)
    mask = np.ones(g.shape, bool)
    local = np.zeros((*g.shape, 2))
    local[4:6, 3:5, 1] = 0.01
    mixed = local + 0.02 * b[0] - 0.01 * b[2] + 0.03 * b[3]
    out = remove_rigid(mixed[None], mask)[0]
    np.testing.assert_allclose(out, remove_rigid(local[None], mask)[0], atol=1e-12)
    with pytest.raises(ValueError, match="mask"):
        remove_rigid(mixed, np.ones((3, 3), bool))


def test_colour_wheel():
    f = np.zeros((4, 4, 2))
    f[0, 0] = (1.0, 0.0)
    f[1, 1] = np.nan
    rgb = flow_to_colour(f)
    assert rgb.shape == (4, 4, 3) and rgb.dtype == np.uint8
    assert rgb[1, 1].tolist() == [255, 255, 255]
    assert rgb[0, 0].tolist() != rgb[2, 2].tolist()


def test_a_face_held_still_at_an_expression_reads_the_same_on_every_frame():
    import pandas as pd

    from faceanalysis.io.table import MUSCLES
    from synth.render.sequence import contraction_timeline, synthesize

    # the reference is a smile; the face then holds still at rest, so every later frame
    # is the same image with the same head frame
    apex = contraction_timeline(MUSCLES, expression="happiness", frames=20).max()
    drive = pd.DataFrame(np.outer([1.0, 0.0], apex.to_numpy()), columns=apex.index)
    seq = synthesize(contractions=drive, frames=2, size=160, seed=11, flow=False,
                     texture_size=256, supersample=1)
    heads = seq.truth[["head_x", "head_y", "head_scale", "head_roll"]].to_numpy()
    frames = [seq.images[0]] + [seq.images[1]] * 6
    ff = face_flow(frames, np.vstack([heads[0]] + [heads[1]] * 6), stabilization="flow")
    d = ff.displacement
    assert np.abs(d[1]).max() > 0.02                  # the smile's relaxation is seen
    # the same image reads the same: the alignment does not feed back on itself
    for k in range(2, len(frames)):
        np.testing.assert_allclose(d[k], d[1], atol=1e-9)
