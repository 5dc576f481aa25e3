import numpy as np
import pytest

from tests.trackers.conftest import ellipse_distance, render_ellipse
from trackers.potentials import gaussian_potential, valley_potential
from trackers.sampling import force_field
from trackers.snake_types import Contour, SnakeParams
from trackers.snakes import ContourSystem, factorization_count, paper_equivalent_strength

SIGMA = 2.0
PARAMS = SnakeParams(p=paper_equivalent_strength(SIGMA))


def test_matrix_is_eq9_and_solve_is_exact(rng):
    t = np.linspace(0, 2 * np.pi, 30, endpoint=False)
    cs = [Contour(np.c_[50 + 20 * np.cos(t), 50 + 20 * np.sin(t)], closed=True,
                  b=rng.uniform(0.3, 1, 30)),
          Contour(np.c_[np.arange(10.0), np.zeros(10)] + 5, fixed_ends=True),
          Contour(np.c_[np.arange(7.0), np.ones(7)] + 5, closed=True)]
    s = ContourSystem(cs)
    A = s.matrix()
    # eq. 9 on the closed contour: beta_i = b_{i+1} d_{i+1} - 2 b_i d_i + b_{i-1} d_{i-1}
    x = rng.normal(size=(s.n_nodes, 2))
    sl = s.contour_slice(0)
    xc = x[sl]
    b = s.b_n[sl]
    d = np.roll(xc, -1, 0) - 2 * xc + np.roll(xc, 1, 0)
    beta = (np.roll(b, -1)[:, None] * np.roll(d, -1, 0) - 2 * b[:, None] * d
            + np.roll(b, 1)[:, None] * np.roll(d, 1, 0))
    np.testing.assert_allclose((A @ x)[sl], 0.5 * xc + beta, atol=1e-12)
    R = rng.normal(size=(s.n_nodes, 2))
    np.testing.assert_allclose(A @ s.solve(R), R, atol=1e-9)


def test_split_tension_matrix_and_same_equilibrium(rng, ellipse_image):
    t = np.linspace(0, 2 * np.pi, 40, endpoint=False)
    pts = np.c_[80 + 55 * np.cos(t), 60 + 34 * np.sin(t)]
    cs = [Contour(pts, closed=True, a=rng.uniform(0.5, 1.5, 40)),
          Contour(np.c_[np.linspace(20, 60, 20), np.full(20, 100.0)], fixed_ends=True)]
    s = ContourSystem(cs, PARAMS, tension="split")
    A = s.matrix()
    R = rng.normal(size=(s.n_nodes, 2))
    np.testing.assert_allclose(A @ s.solve(R), R, atol=1e-9)
    # the split scheme has the same equilibria as the explicit one
    img, g = ellipse_image
    F = force_field(gaussian_potential(img, SIGMA))
    ex = ContourSystem([Contour(pts, closed=True)], PARAMS)
    sp = ContourSystem([Contour(pts, closed=True)], PARAMS, tension="split")
    ex.relax(F, tol=1e-4, max_iter=4000)
    sp.relax(F, tol=1e-4, max_iter=4000)
    for sys_ in (ex, sp):
        d = ellipse_distance(sys_.positions, g["cx"], g["cy"], g["ax"], g["ay"])
        assert d.mean() < 0.5
    with pytest.raises(ValueError, match="tension"):
        ContourSystem(cs, tension="implicit")


def test_closed_contour_converges_to_ellipse(ellipse_image):
    img, g = ellipse_image
    t = np.linspace(0, 2 * np.pi, 160, endpoint=False)
    init = np.c_[g["cx"] + (g["ax"] + 4) * np.cos(t), g["cy"] + (g["ay"] + 4) * np.sin(t)]
    s = ContourSystem([Contour(init, closed=True)], PARAMS)
    res = s.relax(force_field(gaussian_potential(img, SIGMA)), max_iter=3000)
    assert res.converged
    d = ellipse_distance(s.positions, g["cx"], g["cy"], g["ax"], g["ay"])
    assert d.mean() < 0.5
    assert d.max() < 1.5


def test_open_contour_converges_free_and_fixed(ellipse_image):
    img, g = ellipse_image
    F = force_field(gaussian_potential(img, SIGMA))
    tt = np.linspace(0.3, 2.5, 70)
    init = np.c_[g["cx"] + (g["ax"] - 3.5) * np.cos(tt), g["cy"] + (g["ay"] - 3.5) * np.sin(tt)]
    free = ContourSystem([Contour(init)], PARAMS)
    assert free.relax(F, max_iter=3000).converged
    d = ellipse_distance(free.positions, g["cx"], g["cy"], g["ax"], g["ay"])
    assert d.mean() < 0.5
    # fixed ends stay exactly where they were put, the interior still finds the edge
    on_edge = np.c_[g["cx"] + g["ax"] * np.cos(tt), g["cy"] + g["ay"] * np.sin(tt)]
    init2 = on_edge.copy()
    init2[1:-1] = init[1:-1]
    fixed = ContourSystem([Contour(init2, fixed_ends=True)], PARAMS)
    fixed.relax(F, max_iter=3000)
    pos = fixed.positions
    np.testing.assert_allclose(pos[[0, -1]], init2[[0, -1]], atol=1e-5)
    d = ellipse_distance(pos, g["cx"], g["cy"], g["ax"], g["ay"])
    assert d.mean() < 0.5


def test_open_contour_on_noisy_curve_valley(rng):
    # a dark sine-shaped line in noise; the valley potential locks on its centre line
    H, W = 80, 140
    yy, xx = np.mgrid[:H, :W].astype(float)
    centre = 40 + 8 * np.sin(xx / 18.0)
    img = 200 - 150 * np.exp(-((yy - centre) ** 2) / (2 * 2.0**2))
    img = np.clip(img + rng.normal(0, 8, img.shape), 0, 255).astype(np.uint8)
    xs = np.linspace(15, 125, 60)
    init = np.c_[xs, 40 + 8 * np.sin(xs / 18.0) + 3.0]
    s = ContourSystem([Contour(init)], SnakeParams(p=0.02))
    assert s.relax(force_field(valley_potential(img, 2.5)), max_iter=3000).converged
    pos = s.positions
    err = np.abs(pos[:, 1] - (40 + 8 * np.sin(pos[:, 0] / 18.0)))
    assert err[5:-5].mean() < 0.5


def test_tracks_edge_moving_two_pixels_per_frame():
    H, W = 100, 100
    t = np.linspace(0, 2 * np.pi, 100, endpoint=False)
    cx0, cy, r = 35.0, 50.0, 18.0
    init = np.c_[cx0 + r * np.cos(t), cy + r * np.sin(t)]
    s = ContourSystem([Contour(init, closed=True)], PARAMS)
    before = factorization_count()
    for k in range(12):
        cx = cx0 + 2.0 * k
        img = render_ellipse((H, W), cx, cy, r, r)
        s.relax(force_field(gaussian_potential(img, SIGMA)), max_iter=2000)
        d = ellipse_distance(s.positions, cx, cy, r, r)
        assert d.mean() < 0.5, (k, d.mean())
    assert factorization_count() == before  # every frame reuses the one factor


def test_breaks_decouple_contours():
    a = np.c_[np.linspace(10, 40, 16), np.full(16, 20.0)]
    b = np.c_[np.linspace(41, 71, 16), np.full(16, 20.0)]  # 1 px from a's end
    s = ContourSystem([Contour(a, name="a"), Contour(b, name="b")])
    F = np.zeros((50, 90, 2), np.float32)
    push = np.zeros((32, 2))
    push[:16, 1] = 0.3  # pull only contour a downwards
    push[15, 0] = 0.5  # and its last node toward b
    s.relax(F, user_forces=push, tol=0, max_iter=50, min_iter=50)
    np.testing.assert_allclose(s.contour_points("b"), b, atol=1e-9)
    assert (s.contour_points("a")[:, 1] > 25).all()
    # the matrix has no coupling between the blocks
    A = s.matrix()
    assert np.abs(A[:16, 16:]).max() == 0
    # a single contour with a_i = b_i = 0 at the break behaves the same as two contours
    one = np.vstack([a, b])
    av = np.ones(32)
    bv = np.full(32, 0.5)
    av[15] = 0  # spring between node 15 and 16
    bv[[15, 16]] = 0  # no stencil centred on either side of the jump
    bv[[0, 31]] = 0
    s1 = ContourSystem([Contour(one, a=av, b=bv)])
    s1.relax(F, user_forces=push, tol=0, max_iter=50, min_iter=50)
    np.testing.assert_allclose(s1.positions, s.positions, atol=1e-9)


def test_factorisation_happens_once_per_system(ellipse_image):
    img, g = ellipse_image
    F = force_field(gaussian_potential(img, SIGMA))
    t = np.linspace(0, 2 * np.pi, 60, endpoint=False)
    before = factorization_count()
    s = ContourSystem([Contour(np.c_[80 + 55 * np.cos(t), 60 + 34 * np.sin(t)], closed=True),
                       Contour(np.c_[np.linspace(20, 60, 20), np.full(20, 100.0)])], PARAMS)
    assert factorization_count() == before + 1
    for _ in range(5):
        s.relax(F, max_iter=200)
        s.step(F, 3)
    s.set_contour(1, np.c_[np.linspace(20, 60, 20), np.full(20, 90.0)])
    s.relax(F, max_iter=50)
    assert factorization_count() == before + 1


def test_viscoelastic_rest_lengths_follow_eq8():
    pts = np.c_[np.linspace(10, 30, 11), np.full(11, 10.0)]
    s = ContourSystem([Contour(pts, rest_lengths=1.0, b=0.0)], SnakeParams(a=0.1))
    F = np.zeros((30, 50, 2), np.float32)
    l0 = s.rest_lengths(0)[:-1].copy()
    e0 = 2.0 - l0
    s.step(F, 1)
    np.testing.assert_allclose(s.rest_lengths(0)[:-1], l0 + 0.2 * 1.0 * e0)
    # with nu = 0 the rest lengths never change and the chain contracts toward them
    s2 = ContourSystem([Contour(pts, rest_lengths=1.0, nu=0.0, b=0.0)], SnakeParams(a=0.1))
    s2.step(F, 400)
    assert np.allclose(s2.rest_lengths(0)[:-1], 1.0)
    length = np.hypot(*np.diff(s2.positions, axis=0).T).sum()
    assert length == pytest.approx(10.0, abs=0.05)


def test_equilibrium_by_movement_threshold(ellipse_image):
    img, g = ellipse_image
    F = force_field(gaussian_potential(img, SIGMA))
    t = np.linspace(0, 2 * np.pi, 120, endpoint=False)
    init = np.c_[g["cx"] + (g["ax"] + 2) * np.cos(t), g["cy"] + (g["ay"] + 2) * np.sin(t)]
    s = ContourSystem([Contour(init, closed=True)], PARAMS)
    loose = s.relax(F, tol=1e-2, max_iter=5000)
    s2 = ContourSystem([Contour(init, closed=True)], PARAMS)
    tight = s2.relax(F, tol=1e-3, max_iter=5000)
    assert loose.converged and tight.converged
    assert loose.iterations < tight.iterations < 5000
    assert loose.max_move < 1e-2 and tight.max_move < 1e-3
    again = s2.relax(F, tol=2e-3)
    assert again.iterations == 1  # already at equilibrium


def test_each_contour_stops_at_its_own_equilibrium(rng):
    # two contours on one dark line: one starts on it, the other off it.
    # With 'each' the near one stops on its own first step below tol, wherever the
    # far one still is; with 'max' it went on creeping until the far one stopped
    H, W = 80, 260
    yy, xx = np.mgrid[:H, :W].astype(float)
    img = 200 - 150 * np.exp(-((yy - 40 - 8 * np.sin(xx / 18.0)) ** 2) / (2 * 2.0**2))
    img = np.clip(img + rng.normal(0, 8, img.shape), 0, 255).astype(np.uint8)
    F = force_field(valley_potential(img, 2.5))
    xs = np.linspace(15, 115, 40)
    near = np.c_[xs, 40 + 8 * np.sin(xs / 18.0)]
    far = np.c_[xs + 130, 40 + 8 * np.sin((xs + 130) / 18.0) + 5.0]
    prm = SnakeParams(p=0.02)
    alone = ContourSystem([Contour(near)], prm)
    r1 = alone.relax(F, criterion="each", tol=0.01, max_iter=3000)
    pair = ContourSystem([Contour(near), Contour(far)], prm)
    r2 = pair.relax(F, criterion="each", tol=0.01, max_iter=3000)
    assert r1.converged and r2.converged and r2.iterations > r1.iterations
    np.testing.assert_allclose(pair.contour_points(0), alone.positions, atol=1e-12)
    err = np.abs(pair.positions[:, 1] - (40 + 8 * np.sin(pair.positions[:, 0] / 18.0)))
    assert np.median(err) < 0.5  # both on the line
    with pytest.raises(ValueError, match="'max', 'rms' or 'each'"):
        pair.relax(F, criterion="all")


@pytest.mark.parametrize("pts, closed", [
    (np.zeros((2, 2)) + 5, False),
    (np.c_[np.arange(4.0), np.zeros(4)] + 5, True),
])
def test_too_few_nodes(pts, closed):
    with pytest.raises(ValueError, match="rigidity stencil"):
        ContourSystem([Contour(pts, closed=closed)])


def test_bad_contours_and_nodes_outside():
    with pytest.raises(ValueError, match="NaN"):
        ContourSystem([np.array([[1.0, 2], [np.nan, 3], [4, 5]])])
    with pytest.raises(ValueError, match="shape"):
        ContourSystem([np.zeros((5, 3))])
    with pytest.raises(ValueError, match="positive"):
        SnakeParams(gamma=0)
    with pytest.raises(ValueError, match=">= 0"):
        SnakeParams(p=-1)
    s = ContourSystem([Contour(np.c_[np.linspace(5, 40, 10), np.full(10, 5.0)], name="brow")])
    F = np.zeros((20, 30, 2), np.float32)
    with pytest.raises(ValueError, match="contour 'brow'.*outside the image"):
        s.relax(F)
    with pytest.raises(ValueError, match="forces must"):
        s.relax(np.zeros((20, 30)))
    with pytest.raises(ValueError, match="user_forces"):
        s.relax(np.zeros((20, 50, 2)), user_forces=np.zeros((3, 2)))


def test_springs_pull_nodes_to_their_targets_where_the_image_is_flat():
    pts = np.c_[np.linspace(10, 50, 9), np.full(9, 30.0)]
    sys_ = ContourSystem([Contour(pts, spring=0.5)])
    target = pts + [0.0, 4.0]
    sys_.set_targets(0, target)
    flat = np.zeros((64, 64))
    r = sys_.relax(potentials=flat, tol=1e-4, max_iter=500)
    assert r.converged
    np.testing.assert_allclose(sys_.contour_points(0), target, atol=1e-2)


def test_a_spring_shares_a_node_with_the_image_force():
    # a dark horizontal line at y = 30 and a target 3 px below it: a weak spring leaves
    # the node near the line, a stiff one takes it to the target
    yy = np.arange(64)[:, None] * np.ones((1, 64))
    P = -100.0 * np.exp(-0.5 * ((yy - 30.0) / 2.0) ** 2)
    ends = []
    for k in (0.001, 5.0):
        pts = np.c_[np.linspace(10, 50, 9), np.full(9, 30.0)]
        s = ContourSystem([Contour(pts, spring=k, p=0.05)])
        s.set_targets(0, pts + [0.0, 3.0])
        s.relax(potentials=P, tol=1e-5, max_iter=5000)
        ends.append(s.contour_points(0)[:, 1].mean())
    assert ends[0] < 30.3 and ends[1] > 32.0


def test_targets_are_checked():
    s = ContourSystem([Contour(np.c_[np.arange(5.0), np.zeros(5)], spring=1.0)])
    with pytest.raises(ValueError, match="targets"):
        s.set_targets(0, np.zeros((4, 2)))
    with pytest.raises(ValueError, match="spring"):
        ContourSystem([Contour(np.c_[np.arange(5.0), np.zeros(5)], spring=-1.0)])


def _two_field_system():
    a = Contour(np.c_[np.linspace(8, 30, 8), np.full(8, 12.0)], field=0, name="a")
    b = Contour(np.c_[np.full(8, 20.0), np.linspace(10, 40, 8)], field=1, name="b")
    return ContourSystem([a, b], SnakeParams(p=0.05))


def test_fields_of_different_shapes_give_the_same_relaxation_on_every_call():
    # potentials of different shapes share one block that the system keeps: what an
    # earlier call left in it must not change a later relaxation
    rng = np.random.default_rng(3)
    small = [-(rng.random((30, 40)) * 50).astype(np.float32),
             -(rng.random((50, 35)) * 50).astype(np.float32)]
    large = [-(rng.random((70, 80)) * 50).astype(np.float32),
             -(rng.random((60, 90)) * 50).astype(np.float32)]
    fresh = _two_field_system()
    fresh.relax(potentials=small, tol=0.0, max_iter=20)
    reused = _two_field_system()
    reused.relax(potentials=large, tol=0.0, max_iter=1)
    reused.X[:] = _two_field_system().X
    reused.rest[:] = _two_field_system().rest
    reused.relax(potentials=small, tol=0.0, max_iter=20)
    np.testing.assert_array_equal(reused.X, fresh.X)


def test_non_finite_or_outside_fields_of_different_shapes_are_refused():
    s = _two_field_system()
    bad = [np.zeros((30, 40), np.float32), np.zeros((50, 35), np.float32)]
    bad[1][49, 34] = np.nan          # outside contour b's reach, still refused
    with pytest.raises(ValueError, match="NaN or infinite"):
        s.relax(potentials=bad)
    with pytest.raises(ValueError, match="contour 'b'.*outside the image"):
        s.relax(potentials=[np.zeros((30, 40)), np.zeros((30, 35))])   # b reaches y=40
    # a refused call leaves nothing behind
    good = [-np.ones((30, 40), np.float32), -np.ones((50, 35), np.float32)]
    good[0][:, 15:] = -3.0
    fresh = _two_field_system()
    fresh.relax(potentials=good, tol=0.0, max_iter=5)
    s.relax(potentials=good, tol=0.0, max_iter=5)
    np.testing.assert_array_equal(s.X, fresh.X)


def test_a_frozen_contour_stays_put_reads_no_field_and_leaves_the_others_as_they_were():
    yy, xx = np.mgrid[:64, :64]
    img = ((xx - 32) ** 2 + (yy - 32) ** 2 < 15 ** 2).astype(float)
    P = gaussian_potential(img, 2.0).astype(np.float32)
    t = np.linspace(0, 2 * np.pi, 40, endpoint=False)
    ring = Contour(np.c_[32 + 18 * np.cos(t), 32 + 18 * np.sin(t)], closed=True)
    line = np.c_[np.linspace(80, 120, 10), np.full(10, 90.0)]      # off every field
    params = SnakeParams(p=paper_equivalent_strength(2.0))
    alone = ContourSystem([ring], params)
    ref = alone.relax(potentials=P, max_iter=300)
    both = ContourSystem([ring, line], params)
    both.freeze(1)
    # the frozen contour's field may be any 2x2 array: its nodes read none
    res = both.relax(potentials=[P, np.zeros((2, 2), np.float32)], origin=[(0, 0), (0, 0)],
                     max_iter=300)
    np.testing.assert_array_equal(both.contour_points(1), line)
    np.testing.assert_allclose(both.contour_points(0), alone.contour_points(0), atol=1e-12)
    assert res.iterations == ref.iterations and not res.outside.any()
    assert not both.outside_fields([(64, 64), (2, 2)], [(0, 0), (0, 0)]).any()
    both.freeze(1, False)                  # back in: now it must lie in its field
    with pytest.raises(ValueError, match="outside"):
        both.relax(potentials=[P, np.zeros((2, 2), np.float32)], origin=[(0, 0), (0, 0)])
