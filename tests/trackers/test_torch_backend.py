"""The torch backend gives the NumPy/Numba backend's potentials and contours."""

import subprocess
import sys

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("kornia")

from tests.trackers.conftest import draw_face, render_ellipse  # noqa: E402
from trackers import Tracker, layout_from_eyes  # noqa: E402
from trackers.potentials import potential_from_gray, to_gray  # noqa: E402
from trackers.sampling import force_field, sample_bilinear  # noqa: E402
from trackers.snake_types import Contour, SnakeParams  # noqa: E402
from trackers.snakes import (  # noqa: E402
    ContourSystem,
    factorization_count,
    paper_equivalent_strength,
)
from trackers.torch_backend import (  # noqa: E402
    TorchContourSystem,
    TorchTracker,
    check_backend,
    force_field_batch,
    make_tracker,
    potential_batch,
    sample_bilinear_batch,
    snake_relax_batch,
)

TOL_PX = 0.05  # the equivalence bound
EYES = ((96.0, 105.0), (159.0, 105.0))


def _t(a):
    return torch.from_numpy(np.ascontiguousarray(a, dtype=np.float64))


def _ellipse(shape=(120, 160), cx=80.3, cy=60.7, ax=50.0, ay=30.0, seed=0):
    rng = np.random.default_rng(seed)
    img = render_ellipse(shape, cx, cy, ax, ay).astype(np.float32)
    return np.clip(img + rng.normal(0, 4, img.shape), 0, 255).astype(np.uint8)


def _curve_image(shape=(100, 140), amp=10.0, y0=50.0, width=4):
    """A dark sinuous band (a brow-like valley) on a bright background."""
    import cv2

    img = np.full(shape, 200, np.uint8)
    x = np.linspace(15, shape[1] - 15, 200)
    pts = np.c_[x, y0 + amp * np.sin(x / 20.0)]
    cv2.polylines(img, [np.round(pts * 16).astype(np.int32)], False, 50, width,
                  cv2.LINE_AA, shift=4)
    return cv2.GaussianBlur(img, (0, 0), 0.8), pts


# --------------------------------------------------------------------- potentials

@pytest.mark.parametrize("kind", ["edge", "valley", "dark_below"])
@pytest.mark.parametrize("sigma", [1.5, 2.5])
def test_potential_batch_matches_numpy(kind, sigma):
    imgs = [_ellipse(seed=0), _ellipse(seed=1, cx=70.0)]
    grays = [to_gray(i) for i in imgs]
    P = potential_batch(_t(np.stack(grays))[:, None], kind, sigma)
    assert P.shape == (2, 1, 120, 160) and P.dtype == torch.float64
    for b, g in enumerate(grays):
        ref = potential_from_gray(g, kind, sigma)
        scale = float(np.abs(ref).max())
        # the NumPy backend blurs in float32 (OpenCV); the rest is the same arithmetic
        np.testing.assert_allclose(P[b, 0].numpy(), ref, atol=2e-5 * scale)


def test_force_field_batch_matches_numpy_with_ragged_sizes():
    rng = np.random.default_rng(2)
    P1 = rng.normal(size=(20, 30)).astype(np.float32)
    P2 = rng.normal(size=(12, 17)).astype(np.float32)
    stack = np.zeros((1, 2, 20, 30))
    stack[0, 0] = P1
    stack[0, 1, :12, :17] = P2
    F = force_field_batch(_t(stack), sizes=[[[20, 30], [12, 17]]])
    assert F.shape == (1, 2, 2, 20, 30)
    np.testing.assert_allclose(F[0, 0].permute(1, 2, 0).numpy(), force_field(P1), atol=1e-6)
    np.testing.assert_allclose(F[0, 1, :, :12, :17].permute(1, 2, 0).numpy(), force_field(P2),
                               atol=1e-6)


def test_sample_bilinear_batch_pixel_centre_convention():
    rng = np.random.default_rng(4)
    f = rng.normal(size=(2, 3, 9, 13))
    pts = np.c_[rng.uniform(0, 12, 40), rng.uniform(0, 8, 40)]
    pts[0] = (12.0, 8.0)  # the last pixel centre is inside
    pts[1] = (3.0, 5.0)  # an integer point is exactly a pixel
    pts = np.stack([pts, pts[::-1] + 20.0])
    origin = np.array([[0.0, 0.0], [20.0, 20.0]])
    v = sample_bilinear_batch(_t(f), _t(pts), origin=_t(origin)).numpy()
    assert v.shape == (2, 40, 3)
    for b in range(2):
        ref = sample_bilinear(np.moveaxis(f[b], 0, -1), pts[b], origin=origin[b])
        np.testing.assert_allclose(v[b], ref, atol=1e-12)
    np.testing.assert_allclose(v[0, 1], f[0, :, 5, 3], atol=1e-12)
    out = sample_bilinear_batch(_t(f), _t(np.array([[[13.5, 2.0]], [[-0.1, 3.0]]])))
    assert torch.isnan(out).all()


# --------------------------------------------------------------------- relaxation

def _relax_pair(contours, pot, *, origin=(0.0, 0.0), system_kw=None, relax_kw=None,
                dtype=None):
    prm = SnakeParams(p=paper_equivalent_strength(2.0))
    ref = ContourSystem(contours, prm, **(system_kw or {}))
    ts = TorchContourSystem(ref, dtype=dtype)
    kw = dict(tol=1e-3, max_iter=400) | (relax_kw or {})
    r_np = ref.relax(potentials=pot, origin=origin, **kw)
    if isinstance(pot, list):
        H = max(p.shape[0] for p in pot)
        W = max(p.shape[1] for p in pot)
        stack = np.zeros((1, len(pot), H, W))
        for k, p in enumerate(pot):
            stack[0, k, :p.shape[0], :p.shape[1]] = p
        sizes = [[p.shape for p in pot]]
    else:
        stack, sizes = np.asarray(pot)[None, None], None
    r_t = ts.relax(potentials=_t(stack), origin=np.asarray(origin, float), sizes=sizes, **kw)
    return ref, ts, r_np, r_t


def _ellipse_contour(cx=80.3, cy=60.7, ax=50.0, ay=30.0, grow=1.15, n=60):
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    return np.c_[cx + grow * ax * np.cos(t), cy + grow * ay * np.sin(t)]


@pytest.mark.parametrize("options", [
    dict(),
    dict(normal_forces=True),
    dict(max_step=0.3),
    dict(tension="split"),
    dict(criterion="rms"),
    dict(criterion="each"),
    dict(fixed_ends=True),
])
def test_relax_matches_numpy_backend(options):
    opts = dict(options)
    system_kw = {k: opts.pop(k) for k in ("max_step", "tension") if k in opts}
    relax_kw = {k: opts.pop(k) for k in ("criterion",) if k in opts}
    normal = opts.pop("normal_forces", False)
    fixed = opts.pop("fixed_ends", False)
    img, band = _curve_image()
    pot_band = potential_from_gray(to_gray(img), "valley", 2.0)
    ell = potential_from_gray(to_gray(_ellipse()), "edge", 2.0)
    # two fields of different sizes and origins: an edge ellipse, a valley band
    band_init = band[20:180:8] + [0.0, 3.0]
    contours = [Contour(_ellipse_contour(), closed=True, normal_forces=normal, field=0),
                Contour(band_init + [200.0, 0.0], normal_forces=normal, fixed_ends=fixed,
                        field=1)]
    ref, ts, r_np, r_t = _relax_pair(contours, [ell, pot_band],
                                     origin=[(0.0, 0.0), (200.0, 0.0)],
                                     system_kw=system_kw, relax_kw=relax_kw)
    d = np.hypot(*(ts.positions(0) - ref.positions).T)
    assert d.max() <= TOL_PX, d.max()
    assert d.max() < 1e-6  # in float64 the two backends do the same arithmetic
    np.testing.assert_allclose(ts.rest_lengths(0), ref.rest, atol=1e-6)
    assert r_t.iterations[0] == r_np.iterations
    assert bool(r_t.converged[0]) == r_np.converged
    np.testing.assert_array_equal(r_t.outside[0], r_np.outside)
    if fixed:
        np.testing.assert_allclose(ref.contour_points(1)[[0, -1]],
                                   contours[1].points[[0, -1]], atol=1e-4)


def test_float32_contours_within_tolerance():
    pot = potential_from_gray(to_gray(_ellipse()), "edge", 2.0)
    ref, ts, r_np, r_t = _relax_pair([Contour(_ellipse_contour(), closed=True)], pot,
                                     dtype=torch.float32,
                                     relax_kw=dict(tol=0.01, max_iter=2000))
    assert r_np.converged and r_t.converged[0]
    assert np.hypot(*(ts.positions(0) - ref.positions).T).max() <= TOL_PX


def test_batched_relaxation_equals_one_by_one():
    geoms = [dict(cx=80.3, cy=60.7, ax=50.0, ay=30.0), dict(cx=75.0, cy=58.0, ax=45.0, ay=33.0),
             dict(cx=82.0, cy=62.0, ax=38.0, ay=24.0)]
    pots = [potential_from_gray(to_gray(_ellipse(seed=i, **g)), "edge", 2.0)
            for i, g in enumerate(geoms)]
    prm = SnakeParams(p=paper_equivalent_strength(2.0))
    # ragged: different node counts and contour counts per element
    systems = [ContourSystem([Contour(_ellipse_contour(**g, n=40 + 10 * i), closed=True)]
                             + ([Contour(_ellipse_contour(**g, grow=0.8)[5:20])] if i == 1
                                else []), prm)
               for i, g in enumerate(geoms)]
    fields = np.stack(pots)[:, None].repeat(2, axis=1)
    batch = TorchContourSystem(systems)
    res = batch.relax(potentials=_t(fields), tol=1e-3, max_iter=500)
    assert len(set(res.iterations.tolist())) > 1  # they stop at different steps
    for b, s in enumerate(systems):
        single = TorchContourSystem(s)
        r1 = single.relax(potentials=_t(fields[b:b + 1]), tol=1e-3, max_iter=500)
        assert r1.iterations[0] == res.iterations[b]
        np.testing.assert_allclose(batch.positions(b), single.positions(0), atol=1e-10)
        r_np = s.relax(potentials=list(fields[b]), tol=1e-3, max_iter=500)
        assert r_np.iterations == res.iterations[b]
        assert np.hypot(*(batch.positions(b) - s.positions).T).max() <= TOL_PX


def test_inverse_is_the_matrix_of_eq_11_and_factored_once():
    contours = [Contour(_ellipse_contour(), closed=True),
                Contour(_ellipse_contour(grow=0.7)[3:25], fixed_ends=True)]
    ref = ContourSystem(contours, SnakeParams(), tension="split")
    before = factorization_count()
    ts = TorchContourSystem(ref, batch=5)
    assert ts.n_factorizations == 1 and factorization_count() == before
    rng = np.random.default_rng(1)
    rhs = rng.normal(size=(ref.n_nodes, 2))
    padded = ts.pad([rhs] * 5)
    out = ts.solve(padded).numpy().reshape(5, -1, 2)[:, ts._flat[0]]
    np.testing.assert_allclose(out[3], np.linalg.solve(ref.matrix(), rhs), rtol=1e-8,
                               atol=1e-9)


def test_snake_relax_batch_functional():
    img, band = _curve_image()
    pot = potential_from_gray(to_gray(img), "valley", 2.0)
    F = force_field_batch(_t(pot)[None, None])[:, 0]
    inits = np.stack([band[20:180:8] + [0.0, dy] for dy in (-3.0, 2.0, 3.5)])
    prm = SnakeParams(p=paper_equivalent_strength(2.0))
    out, res, factor = snake_relax_batch(_t(inits), F.expand(3, 2, *pot.shape), params=prm,
                                         normal_forces=True, max_step=1.0, tol=1e-3)
    assert out.shape == (3, 20, 2)
    for b in range(3):
        s = ContourSystem([Contour(inits[b], normal_forces=True)], prm, max_step=1.0)
        r = s.relax(force_field(pot), tol=1e-3)
        assert r.iterations == res.iterations[b]
        assert np.hypot(*(out[b].numpy() - s.positions).T).max() < 1e-6
    # the factor is reused: no new matrix
    before = factorization_count()
    out2, _, _ = snake_relax_batch(_t(inits), F.expand(3, 2, *pot.shape), params=prm,
                                   normal_forces=True, max_step=1.0, factor=factor, n_steps=3)
    assert factorization_count() == before and out2.shape == (3, 20, 2)


# --------------------------------------------------------------------- trackers

def _face_frames(n, shift=(0.0, 0.0), vanish_brows_at=None):
    frames = []
    rng = np.random.default_rng(7)
    for k in range(n):
        eyes = tuple((x + 0.8 * k + shift[0], y + 0.4 * k + shift[1]) for x, y in EYES)
        img, _ = draw_face(eyes=eyes, brow_raise=0.01 * k, noise=3, rng=rng)
        if vanish_brows_at is not None and k == vanish_brows_at:
            img[70:100, 70:190] = 190
        frames.append(img)
    return frames


def _max_diff(a, b):
    return max(float(np.hypot(*(a.contours[n] - b.contours[n]).T).max()) for n in a.contours)


def test_tracker_on_torch_backend_matches_numpy():
    lay = layout_from_eyes(*EYES, (256, 256))
    ref, tt = Tracker(lay), make_tracker(lay, backend="torch", device="cpu")
    for img in _face_frames(3):
        a, b = ref.track(img), tt.track(img)
        assert _max_diff(a, b) <= TOL_PX
        assert a.iterations == b.iterations
        assert {n: q.lost for n, q in a.quality.items()} == \
            {n: q.lost for n, q in b.quality.items()}
        for n in a.fiducials:
            assert np.hypot(*(np.subtract(a.fiducials[n], b.fiducials[n]))) <= TOL_PX


def test_torch_tracker_batches_videos_like_separate_trackers():
    lays = [layout_from_eyes(*EYES, (256, 256)),
            layout_from_eyes((93.0, 103.0), (161.0, 104.0), (256, 256))]
    videos = [_face_frames(3), _face_frames(3, shift=(-2.0, -1.0), vanish_brows_at=2)]
    refs = [Tracker(lay) for lay in lays]
    batch = TorchTracker(lays)
    for frames in zip(*videos):
        got = batch.track(list(frames))
        for b, img in enumerate(frames):
            want = refs[b].track(img)
            assert _max_diff(want, got[b]) <= TOL_PX
            assert want.iterations == got[b].iterations
            assert want.success == got[b].success
    # the second video lost its brows on the last frame (re-initialised alone)
    assert got[0].success and not got[1].success
    assert got[1].quality["brow_l"].reinitialised


# --------------------------------------------------------------------- errors

def test_shape_checks_name_the_dimensions():
    with pytest.raises(ValueError, match=r"\[B, 1, H, W\]"):
        potential_batch(torch.zeros(2, 16, 16, dtype=torch.float64))
    with pytest.raises(ValueError, match=r"\[B, 1, H, W\]"):
        potential_batch(torch.zeros(2, 3, 16, 16, dtype=torch.float64))
    with pytest.raises(ValueError, match="kind"):
        potential_batch(torch.zeros(1, 1, 16, 16), "ridge")
    with pytest.raises(ValueError, match=r"\[B, N, 2\]"):
        sample_bilinear_batch(torch.zeros(2, 1, 5, 5), torch.zeros(3, 4, 2))
    with pytest.raises(ValueError, match=r"\[B, C, H, W\]"):
        force_field_batch(torch.zeros(5, 5))
    ts = TorchContourSystem(ContourSystem([Contour(_ellipse_contour(), closed=True)]), batch=2)
    with pytest.raises(ValueError, match=r"\[B, Kf, H, W\] with B = 2"):
        ts.relax(potentials=torch.zeros(3, 1, 130, 170, dtype=torch.float64))
    with pytest.raises(ValueError, match="outside its field"):
        ts.relax(potentials=torch.zeros(2, 1, 50, 50, dtype=torch.float64))
    with pytest.raises(ValueError, match="exactly one"):
        ts.relax()


def test_backend_and_device_choices():
    lay = layout_from_eyes(*EYES, (256, 256))
    with pytest.raises(ValueError, match="backend"):
        make_tracker(lay, backend="jax")
    with pytest.raises(ValueError, match="needs backend='torch'"):
        make_tracker(lay, backend="numpy", device="cuda")
    if not torch.cuda.is_available():
        with pytest.raises(ValueError, match="CUDA"):
            make_tracker(lay, backend="torch", device="cuda")
    with pytest.raises(ValueError, match="device"):
        make_tracker(lay, backend="torch", device="abacus")
    check_backend("torch", "cpu")
    with pytest.raises(ValueError, match="backend"):
        check_backend("tensorflow")


def test_trackers_import_without_torch():
    code = (
        "import sys\n"
        "sys.modules['torch'] = None; sys.modules['kornia'] = None\n"
        "import trackers, trackers.torch_backend as tb\n"
        "lay = trackers.layout_from_eyes((96, 105), (159, 105), (256, 256))\n"
        "assert type(tb.make_tracker(lay)).__name__ == 'Tracker'\n"
        "tb.check_backend('numpy', 'cpu')\n"
        "try:\n"
        "    tb.make_tracker(lay, backend='torch')\n"
        "except ImportError as exc:\n"
        "    print(exc)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True)
    assert "the torch backend needs the [torch] extra: pip install torch==2.13.0 kornia" \
        in out.stdout


def test_ragged_field_sequences_equal_padded_tensor_and_forces():
    img, band = _curve_image()
    pot_band = potential_from_gray(to_gray(img), "valley", 2.0)[10:90, 5:135]
    ell = potential_from_gray(to_gray(_ellipse()), "edge", 2.0)
    contours = [Contour(_ellipse_contour(), closed=True, field=1),
                Contour(band[20:180:8] + [0.0, 3.0], normal_forces=True, field=0)]
    origin = [(5.0, 10.0), (0.0, 0.0)]
    runs = []
    for form in ("sequence", "tensor", "forces"):
        ts = TorchContourSystem(ContourSystem(contours, SnakeParams(p=0.05)))
        if form == "sequence":
            r = ts.relax(potentials=[[pot_band, ell]], origin=origin, tol=1e-3)
        else:
            stack = np.zeros((1, 2, 120, 160))
            stack[0, 0, :80, :130] = pot_band
            stack[0, 1] = ell
            sizes = [[[80, 130], [120, 160]]]
            if form == "tensor":
                r = ts.relax(potentials=_t(stack), sizes=sizes, origin=origin, tol=1e-3)
            else:
                F = force_field_batch(_t(stack), sizes=sizes)
                r = ts.relax(F, sizes=sizes, origin=origin, tol=1e-3)
        runs.append((ts.positions(0), int(r.iterations[0])))
    ref = ContourSystem(contours, SnakeParams(p=0.05))
    r_np = ref.relax(potentials=[pot_band, ell], origin=origin, tol=1e-3)
    for pos, iters in runs:
        assert iters == r_np.iterations
        assert np.hypot(*(pos - ref.positions).T).max() < 1e-6


def test_torch_tracker_names_the_video_with_a_bad_frame():
    lay = layout_from_eyes(*EYES, (256, 256))
    img, _ = draw_face()
    tt = TorchTracker([lay, lay])
    with pytest.raises(ValueError, match="video 1: frame 0 is 100x100"):
        tt.track([img, np.zeros((100, 100), np.uint8)])
    got = TorchTracker([lay, lay]).track([img, np.zeros((100, 100), np.uint8)],
                                         errors="return")
    assert got[0].success and isinstance(got[1], ValueError)
