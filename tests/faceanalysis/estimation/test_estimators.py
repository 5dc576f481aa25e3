import numpy as np
import pytest

from faceanalysis.estimation.calibration import calibrate, find_suspect
from faceanalysis.estimation.estimators import (
    estimate,
    estimate_joint,
    estimate_tw93,
    fit_residual,
)
from faceanalysis.estimation.response import FiducialResponse
from faceanalysis.tracking import to_head_frame

FIDS = ("brow_inner_l", "brow_mid_l", "mouth_corner_l", "chin")


def _response(rng, *, saturation=0.3):
    """Four controls with overlapping, saturating (biphasic-like) responses."""
    levels = np.linspace(0, 1, 6)
    muscles = ("frontalis_inner_l", "frontalis_major_l", "zygomaticus_major_l", "jaw_rotation")
    upper = np.array([1.0, 1.0, 1.0, 0.3])
    disp = np.zeros((4, 6, 4, 2))
    shape = levels - saturation * levels**2          # monotone, saturating
    disp[0, :, 0] = np.outer(shape, [0.0, 0.5])      # inner brow up
    disp[0, :, 1] = np.outer(shape, [0.0, 0.2])
    disp[1, :, 0] = np.outer(shape, [0.05, 0.25])    # major brow: overlaps inner
    disp[1, :, 1] = np.outer(shape, [0.0, 0.5])
    disp[2, :, 2] = np.outer(shape, [0.6, 0.5])      # corner up and out
    disp[3, :, 3] = np.outer(shape, [0.0, -1.2])     # chin down
    disp[3, :, 2] = np.outer(shape, [0.0, -0.3])     # jaw also drags the corner
    rest = rng.normal(size=(4, 2)) * 3
    return FiducialResponse(muscles, FIDS, rest, disp, upper, levels)


def test_response_interpolates_tabulated_levels(rng):
    resp = _response(rng)
    c = np.zeros((1, 4))
    c[0, 0] = 0.6
    np.testing.assert_allclose(resp.predict(c)[0], resp.displacement[0, 3])
    jac = resp.jacobian(np.full((1, 4), 0.1))
    assert jac.shape == (1, 8, 4)


def test_response_rejects_bad_tables(rng):
    resp = _response(rng)
    bad = resp.displacement.copy()
    bad[:, 0] += 1.0
    with pytest.raises(ValueError, match="level 0"):
        FiducialResponse(resp.muscles, resp.fiducials, resp.rest, bad, resp.upper, resp.levels)
    with pytest.raises(ValueError, match="shape"):
        FiducialResponse(resp.muscles[:2], resp.fiducials, resp.rest, resp.displacement,
                         resp.upper[:2], resp.levels)


def test_joint_recovers_overlapping_muscles_within_bounds(rng):
    resp = _response(rng)
    truth = rng.uniform(0, 1, size=(200, 4)) * resp.upper
    d = resp.predict(truth) + rng.normal(scale=1e-3, size=(200, 4, 2))
    est = estimate_joint(d, resp, regularization=1e-6, sparsity=0)
    assert np.all(est >= 0) and np.all(est <= resp.upper)
    rmse = np.sqrt(np.mean((est - truth) ** 2, axis=0)) / resp.upper
    assert np.all(rmse < 0.02), rmse


def test_sparsity_rests_the_muscles_the_points_do_not_call_for(rng):
    resp = _response(rng)
    truth = np.zeros((300, 4))
    truth[:, 2] = rng.uniform(0.3, 1.0, 300)            # only the zygomaticus acts
    d = resp.predict(truth) + rng.normal(scale=0.02, size=(300, 4, 2))
    plain = estimate_joint(d, resp, sparsity=0)
    ridge = estimate_joint(d, resp, regularization=5e-2, sparsity=0)
    sparse = estimate_joint(d, resp, sparsity=2e-2)
    rest = [0, 1, 3]

    def false(e):
        return np.abs(e[:, rest]).mean()

    def slope(e):
        return np.polyfit(truth[:, 2], e[:, 2], 1)[0]

    # noise reads as small activations of the resting muscles; the L1 term puts more
    # of them back at exactly zero and halves what is left, while the ridge, which
    # shrinks in proportion, barely touches them and takes a tenth off the active one
    assert (sparse[:, rest] == 0).mean() > (plain[:, rest] == 0).mean() + 0.1
    assert false(sparse) < 0.6 * false(plain) and false(ridge) > 0.8 * false(plain)
    assert slope(sparse) > 0.95 and slope(ridge) < 0.9
    rmse = [np.sqrt(np.mean((e[:, 2] - truth[:, 2]) ** 2)) for e in (sparse, ridge)]
    assert rmse[0] < rmse[1], rmse
    for bad in (-1e-3, np.nan):
        with pytest.raises(ValueError, match="sparsity"):
            estimate_joint(d, resp, sparsity=bad)


def test_joint_beats_tw93_when_muscles_overlap(rng):
    resp = _response(rng)
    truth = rng.uniform(0, 1, size=(200, 4)) * resp.upper
    d = resp.predict(truth)
    joint = estimate(d, resp, estimator="joint", regularization=1e-6, sparsity=0)
    tw93 = estimate(d, resp, estimator="tw93")
    err_joint = np.sqrt(np.nanmean((joint - truth) ** 2, axis=0))
    err_tw93 = np.sqrt(np.nanmean((tw93 - truth) ** 2, axis=0))
    # the inner frontalis shares its fiducial with the major frontalis: tw93 over-reads it
    assert err_tw93[0] > 5 * err_joint[0]


def test_tw93_is_exact_for_an_isolated_muscle(rng):
    resp = _response(rng)
    truth = np.zeros((5, 4))
    truth[:, 3] = np.linspace(0, 0.3, 5)          # jaw alone moves the chin
    est = estimate_tw93(resp.predict(truth), resp)
    np.testing.assert_allclose(est[:, 3], truth[:, 3], atol=1e-9)


def test_out_of_range_motion_hits_the_bound_not_beyond(rng):
    resp = _response(rng)
    d = resp.predict(np.array([[0, 0, 1.0, 0]])) * 3.0   # three times the full pull
    est = estimate_joint(d, resp)
    assert est[0, 2] == pytest.approx(1.0)
    assert estimate_tw93(d, resp)[0, 2] == pytest.approx(1.0)


def test_lost_frames_stay_nan_and_others_are_unaffected(rng):
    resp = _response(rng)
    truth = rng.uniform(0, 1, size=(6, 4)) * resp.upper
    d = resp.predict(truth)
    d[2] = np.nan
    est = estimate_joint(d, resp, regularization=1e-6, sparsity=0)
    assert np.isnan(est[2]).all()
    assert np.isfinite(np.delete(est, 2, axis=0)).all()
    assert np.isnan(estimate_tw93(d, resp)[2]).all()


def test_estimators_validate_input(rng):
    resp = _response(rng)
    with pytest.raises(ValueError, match="shape"):
        estimate_joint(np.zeros((3, 5, 2)), resp)
    with pytest.raises(ValueError, match="choose from joint, tw93$"):
        estimate(np.zeros((1, 4, 2)), resp, estimator="magic")
    with pytest.raises(ValueError, match="weights"):
        estimate_joint(np.zeros((1, 4, 2)), resp, weights=np.ones(3))


def test_calibration_undoes_similarity_and_recovers_displacements(rng):
    rest = rng.normal(size=(11, 2)) * 4
    head = np.array([130.0, 40.0, 7.5, 0.2])
    cos, sin = np.cos(head[3]), np.sin(head[3])
    rot = np.array([[cos, -sin], [sin, cos]])

    def to_image(model_pts, h):
        local = model_pts * [1, -1] * 9.0      # 9 px per cm, y flipped
        return local @ rot.T * (h[2] / 7.5) + h[:2]

    cal = calibrate(to_image(rest, head), head, rest)
    assert cal.residual < 1e-9
    motion = rng.normal(scale=0.3, size=(11, 2))
    head2 = np.array([140.0, 35.0, 7.5 * 1.1, 0.2])   # translated and scaled head
    d = cal.model_displacements(to_image(rest + motion, head2)[None], head2[None])
    np.testing.assert_allclose(d[0], motion, atol=1e-9)


def test_head_frame_removes_roll():
    pts = np.array([[[10.0, 0.0]]])
    head = np.array([[0.0, 0.0, 1.0, np.pi / 2]])     # head x axis points down the image
    np.testing.assert_allclose(to_head_frame(pts, head), [[[0.0, -10.0]]], atol=1e-12)


def test_calibration_rejects_degenerate_input():
    rest = np.c_[np.arange(4.0), np.arange(4.0)]
    with pytest.raises(ValueError, match="collinear"):
        calibrate(rest * 10, np.array([0, 0, 1.0, 0]), rest)
    with pytest.raises(ValueError, match="finite"):
        calibrate(np.full((4, 2), np.nan), np.array([0, 0, 1.0, 0]), rest)


def test_a_missing_point_hides_only_the_controls_it_observes(rng):
    resp = _response(rng)
    truth = rng.uniform(0, 1, size=(20, 4)) * resp.upper
    d = resp.predict(truth)
    d[:, 3] = np.nan                  # the chin is out of the frame
    est = estimate_joint(d, resp, regularization=1e-6, sparsity=0)
    assert np.isnan(est[:, 3]).all()  # the jaw only moves the chin... and a bit the corner
    np.testing.assert_allclose(est[:, :2], truth[:, :2], atol=0.05)


def test_calibration_on_the_points_the_neutral_frame_sees():
    rest = np.array([[-3.0, 4.0], [3.0, 4.0], [0.0, -5.0], [-2.0, -3.0], [2.0, -3.0]])
    image = np.c_[100 + 10 * rest[:, 0], 120 - 10 * rest[:, 1]]
    image[2] = np.nan
    seen = np.isfinite(image).all(axis=1)
    cal = calibrate(image, np.array([100.0, 120.0, 10.0, 0.0]), rest, valid=seen)
    assert cal.residual < 1e-9
    d = cal.model_displacements(image[None] + [0.0, -10.0], np.array([[100.0, 120, 10, 0]]))
    np.testing.assert_allclose(d[0, seen], [[0.0, 1.0]] * 4, atol=1e-9)
    assert np.isnan(d[0, 2]).all()


def test_box_qp_matches_a_reference_solver(rng):
    from scipy.optimize import lsq_linear

    from faceanalysis.estimation.estimators import box_qp

    # min 0.5 x'Hx - g'x over a box, with H = A'A and g = A'b: bounded least squares
    a = rng.normal(size=(5, 12, 4))
    b = rng.normal(size=(5, 12))
    lo = -rng.random((5, 4))
    hi = rng.random((5, 4))
    hess = np.matmul(a.transpose(0, 2, 1), a)
    grad0 = np.matmul(a.transpose(0, 2, 1), b[:, :, None])[:, :, 0]
    got = box_qp(hess, grad0, lo, hi, iterations=5000, tol=1e-12)
    for t in range(5):
        ref = lsq_linear(a[t], b[t], bounds=(lo[t], hi[t]), tol=1e-12).x
        np.testing.assert_allclose(got[t], ref, atol=1e-6)


def test_box_qp_solves_each_problem_of_a_batch_on_its_own(rng):
    from faceanalysis.estimation.estimators import box_qp

    a = rng.normal(size=(6, 10, 5))
    hess = np.matmul(a.transpose(0, 2, 1), a)
    grad0 = rng.normal(size=(6, 5)) * [[1], [10], [0.1], [1], [100], [1]]
    lo, hi = -rng.random((6, 5)), rng.random((6, 5))
    both = box_qp(hess, grad0, lo, hi, iterations=400)
    for t in range(6):
        alone = box_qp(hess[t:t + 1], grad0[t:t + 1], lo[t:t + 1], hi[t:t + 1],
                       iterations=400)
        np.testing.assert_array_equal(both[t], alone[0])
        assert np.all(both[t] >= lo[t]) and np.all(both[t] <= hi[t])
    with pytest.raises(ValueError, match="shape"):
        box_qp(hess[:, :4], grad0, lo, hi)


def _badly_scaled_problems(rng, n_t, m, rows):
    """Bounded least squares with variables on scales 300 times apart (a jaw moving hundreds
    of points, a muscle a few), as the controls' Hessians have: (hess, grad0, lo, hi, the
    reference optimum, the scales)."""
    from scipy.optimize import lsq_linear

    scales = np.geomspace(1.0, 300.0, m)
    a = rng.normal(size=(n_t, rows, m)) * scales
    hess = np.matmul(a.transpose(0, 2, 1), a)
    truth = rng.uniform(-0.5, 1.5, size=(n_t, m)) / scales      # some outside the box
    grad0 = np.einsum("tij,tj->ti", hess, truth)
    lo, hi = np.zeros((n_t, m)), np.ones((n_t, m)) / scales
    best = np.stack([lsq_linear(a[t], a[t] @ truth[t], bounds=(lo[t], hi[t]), tol=1e-14,
                                method="bvls").x for t in range(n_t)])
    return hess, grad0, lo, hi, best, scales


def test_box_qp_reaches_the_optimum_of_badly_scaled_problems(rng):
    # condition numbers of 5e4-2e5
    from faceanalysis.estimation.estimators import box_qp

    hess, grad0, lo, hi, best, scales = _badly_scaled_problems(rng, 5, 8, 40)
    x = box_qp(hess, grad0, lo, hi, iterations=400)
    np.testing.assert_allclose(x * scales, best * scales, atol=1e-6)
    assert np.all(x >= lo) and np.all(x <= hi)
    # unscaled, the same iterations leave the flat directions far from the optimum
    plain = box_qp(hess, grad0, lo, hi, iterations=400, precondition=False)
    assert np.abs((plain - best) * scales).max() > 0.05


def test_box_qp_newton_steps_land_on_the_optimum(rng):
    # the projected Newton steps find the optimum's held set and then land on the
    # optimum: a few dozen steps give what a reference bounded least squares gives
    from faceanalysis.estimation.estimators import box_qp

    hess, grad0, lo, hi, best, scales = _badly_scaled_problems(rng, 20, 26, 60)
    x = box_qp(hess, grad0, lo, hi, iterations=30)
    np.testing.assert_allclose(x * scales, best * scales, atol=1e-9)


def test_box_qp_handles_singular_hessians(rng):
    # a control no point moves (a zero row and column) goes to the bound its linear term
    # favours, or stays at 0 without one; two controls that move the points alike (equal
    # columns) share the optimum's value between them
    from faceanalysis.estimation.estimators import box_qp

    a = rng.normal(size=(30, 4))
    a[:, 3] = a[:, 2]
    b = rng.normal(size=30)
    hess = np.zeros((3, 5, 5))
    hess[:, :4, :4] = a.T @ a
    grad0 = np.tile(np.append(a.T @ b, 0.0), (3, 1))
    grad0[0, 4], grad0[1, 4] = 2.0, -2.0
    lo, hi = -np.ones((3, 5)), np.ones((3, 5))
    x = box_qp(hess, grad0, lo, hi)
    np.testing.assert_allclose(x[:, 4], [1.0, -1.0, 0.0], atol=1e-12)

    def objective(v):
        return 0.5 * np.einsum("ti,tij,tj->t", v, hess, v) - (grad0 * v).sum(axis=1)

    fine = box_qp(hess, grad0, lo, hi, iterations=50_000, tol=1e-14, precondition=False)
    assert np.all(objective(x) <= objective(fine) + 1e-9)
    assert np.all(x >= lo) and np.all(x <= hi)


def test_response_predicts_piecewise_linear_plus_interactions(rng):
    resp = _response(rng)
    pairs = np.array([[0, 1], [2, 3]])
    inter = rng.normal(size=(2, 4, 2)) * 0.1
    resp = FiducialResponse(resp.muscles, resp.fiducials, resp.rest, resp.displacement,
                            resp.upper, resp.levels, pairs, inter)
    c = rng.uniform(-0.2, 1.2, size=(50, 4)) * resp.upper      # outside the box too
    u = np.clip(c / resp.upper, 0, 1) * (resp.n_levels - 1)
    i = np.minimum(np.floor(u).astype(int), resp.n_levels - 2)
    f = (u - i)[:, :, None, None]
    m = np.arange(4)
    want = ((1 - f) * resp.displacement[m, i] + f * resp.displacement[m, i + 1]).sum(axis=1)
    v = c / resp.upper
    want += np.einsum("tp,pfk->tfk", v[:, pairs[:, 0]] * v[:, pairs[:, 1]], inter)
    np.testing.assert_allclose(resp.predict(c), want, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(resp.predict(c[0]), want[:1], rtol=1e-12, atol=1e-14)
    with pytest.raises(ValueError, match="finite"):
        resp.predict(np.full(4, np.nan))
    with pytest.raises(ValueError, match="shape"):
        resp.predict(np.zeros((2, 3)))


@pytest.mark.parametrize("n_controls", [1, 4, 5, 6, 7])
def test_normal_equations_are_those_of_the_weighted_jacobian(rng, n_controls):
    # the products run four controls at a time: every remainder of four
    levels = np.linspace(0, 1, 5)
    disp = rng.normal(size=(n_controls, 5, 6, 2))
    disp[:, 0] = 0.0
    upper = rng.uniform(0.5, 2.0, n_controls)
    pairs = np.array([(a, b) for a in range(n_controls) for b in range(a + 1, n_controls)],
                     dtype=np.intp).reshape(-1, 2)
    inter = rng.normal(size=(len(pairs), 6, 2)) * 0.1
    resp = FiducialResponse(tuple(f"m{i}" for i in range(n_controls)),
                            tuple(f"p{i}" for i in range(6)), np.zeros((6, 2)), disp, upper,
                            levels, pairs if len(pairs) else None,
                            inter if len(pairs) else None)
    c = rng.uniform(-0.2, 1.2, size=(40, n_controls)) * upper   # outside the box too
    c[rng.uniform(size=c.shape) < 0.4] = 0.0                  # at rest: pair terms skipped
    sw = rng.uniform(0, 2, size=(40, 12))
    sw[:, 3] = 0.0                                            # a point not seen
    r = rng.normal(size=(40, 12))
    jac = resp.jacobian(c) * sw[:, :, None]
    hess, grad = resp.normal_equations(c, sw, r)
    np.testing.assert_allclose(hess, np.einsum("tkm,tkn->tmn", jac, jac), rtol=1e-12,
                               atol=1e-12)
    np.testing.assert_allclose(grad, np.einsum("tkm,tk->tm", jac, r), rtol=1e-12, atol=1e-12)
    assert np.array_equal(hess, hess.transpose(0, 2, 1))
    with pytest.raises(ValueError, match="shapes"):
        resp.normal_equations(c, sw[:, :6], r)


def test_best_of_keeps_each_frames_lowest_objective(rng):
    # the fit's line search: per frame, the trial whose weighted residual plus penalty is
    # lowest, if it beats the current one; its residuals come back with it
    levels = np.linspace(0, 1, 5)
    disp = rng.normal(size=(3, 5, 6, 2))
    disp[:, 0] = 0.0
    pairs = np.array([[0, 1], [1, 2]], dtype=np.intp)
    resp = FiducialResponse(("a", "b", "c"), tuple(f"p{i}" for i in range(6)),
                            np.zeros((6, 2)), disp, np.ones(3), levels, pairs,
                            rng.normal(size=(2, 6, 2)) * 0.1)
    trials = rng.uniform(0, 1, size=(3, 30, 3))
    trials[:, :5] = trials[:1, :5]                 # equal trials: the first is kept
    sw = rng.uniform(0, 2, size=(30, 12))
    target = rng.normal(size=(30, 12)) * sw
    penalty = rng.uniform(0, 0.5, size=(3, 30))
    penalty[:, :5] = penalty[:1, :5]
    res0 = rng.normal(size=(30, 12))
    resid = np.stack([target - resp.predict(t).reshape(30, 12) * sw for t in trials])
    value = (resid**2).sum(axis=2) + penalty                                # (3, T)
    current = np.median(value, axis=0)
    current[:5] = value[0, :5] + 1.0
    current[5:8] = value.min(axis=0)[5:8] - 1.0      # nothing beats these
    best, res, choice = resp.best_of(trials, target, sw, penalty, current, res0)
    beaten = value.min(axis=0) < current
    np.testing.assert_array_equal(choice, np.where(beaten, value.argmin(axis=0), -1))
    assert np.all(choice[:5] == 0)
    np.testing.assert_allclose(best, np.where(beaten, value.min(axis=0), current), rtol=1e-12)
    kept = np.where(beaten[:, None], resid[np.maximum(choice, 0), np.arange(30)], res0)
    np.testing.assert_allclose(res, kept, rtol=1e-12, atol=1e-14)
    assert not np.shares_memory(res, res0)          # the caller's arrays are left as given
    with pytest.raises(ValueError, match="shape"):
        resp.best_of(trials[:, :, :2], target, sw, penalty, current, res0)
    with pytest.raises(ValueError, match="finite"):
        resp.best_of(np.full_like(trials, np.nan), target, sw, penalty, current, res0)


def test_joint_fit_leaves_the_blas_thread_setting_alone(rng):
    from threadpoolctl import threadpool_info

    before = [(i["filepath"], i["num_threads"]) for i in threadpool_info()]
    resp = _response(rng)
    estimate_joint(resp.predict(np.array([0.4, 0.2, 0.6, 0.1])), resp)
    assert [(i["filepath"], i["num_threads"]) for i in threadpool_info()] == before


def test_robust_fit_discounts_a_point_stuck_where_it_was():
    # two controls seen by five points; on every frame one point does not move (a
    # contour end held where its line fades): least squares is dragged toward zero,
    # the Huber-reweighted fit much less
    levels = np.linspace(0, 1, 5)
    disp = np.zeros((2, 5, 5, 2))
    disp[0, :, :, 1] = np.outer(levels, [1.0, 0.8, 0.6, 0.4, 0.9])
    disp[1, :, :, 0] = np.outer(levels, [0.5, 1.0, 0.7, 0.9, 0.6])
    resp = FiducialResponse(("a", "b"), tuple("pqrst"), np.zeros((5, 2)), disp,
                            np.ones(2), levels)
    truth = np.array([[0.6, 0.4], [0.3, 0.8], [0.9, 0.1]])
    d = resp.predict(truth)
    d[:, 4] = 0.0
    plain = estimate_joint(d, resp, sparsity=0, robust=None)
    robust = estimate_joint(d, resp, sparsity=0)
    err_plain, err_robust = np.abs(plain - truth).max(), np.abs(robust - truth).max()
    assert err_robust < 0.5 * err_plain, (err_plain, err_robust)
    # without an outlier the reweighting changes nothing
    clean = estimate_joint(resp.predict(truth), resp, sparsity=0)
    np.testing.assert_allclose(clean, truth, atol=2e-3)
    for bad in (0.0, -1.0, np.nan):
        with pytest.raises(ValueError, match="robust"):
            estimate_joint(d, resp, robust=bad)
    with pytest.raises(ValueError, match="robust_rounds"):
        estimate_joint(d, resp, robust_rounds=-1)


def test_point_residuals_and_suspect_points(rng):
    rest = rng.normal(size=(12, 2)) * 4
    head = np.array([100.0, 120.0, 10.0, 0.0])
    image = np.c_[100 + 10 * rest[:, 0], 120 - 10 * rest[:, 1]]
    image += rng.normal(scale=0.1, size=image.shape)       # another face: small residuals
    image[11] = np.nan
    seen = np.isfinite(image).all(axis=1)
    cal = calibrate(image, head, rest, valid=seen)
    assert np.isnan(cal.point_residuals[11]) and np.nanmax(cal.point_residuals) < 0.05
    assert not find_suspect(image, head, rest, valid=seen).any()
    # two contours on the wrong feature: both found, not their neighbours
    image[[2, 7]] += [[0.0, 25.0], [-20.0, 10.0]]
    one_fit = calibrate(image, head, rest, valid=seen).point_residuals
    assert np.sum(one_fit > 0.08) > 2             # one fit drags good points off too
    np.testing.assert_array_equal(np.flatnonzero(find_suspect(image, head, rest, valid=seen)),
                                  [2, 7])


def test_debias_keeps_the_prior_choice_and_drops_its_shrinkage(rng):
    resp = _response(rng)
    c = np.array([[0.0, 0.0, 0.5, 0.0]])
    d = resp.predict(c)
    shrunk = estimate_joint(d, resp, sparsity=0.05, robust=None)
    relaxed = estimate_joint(d, resp, sparsity=0.05, robust=None, debias=True)
    assert shrunk[0, 2] < 0.45                       # the prior lowers what it keeps
    assert relaxed[0, 2] == pytest.approx(0.5, abs=0.02)
    np.testing.assert_array_equal(relaxed[0, [0, 1, 3]], shrunk[0, [0, 1, 3]])
    assert (relaxed[0, [0, 1, 3]] == 0).all()


def test_concave_debias_rises_from_rest_where_the_relaxed_lasso_jumps(rng):
    # a muscle whose evidence grows by 0.01 a frame through the prior's threshold
    resp = _response(rng)
    c = np.zeros((51, 4))
    c[:, 2] = np.linspace(0, 0.5, 51)
    d = resp.predict(c)
    relaxed = estimate_joint(d, resp, sparsity=0.2, robust=None, debias=True)[:, 2]
    concave = estimate_joint(d, resp, sparsity=0.2, robust=None, debias=0.2)[:, 2]
    assert np.diff(relaxed).max() > 0.1                # rest to 0.13 in one frame
    assert np.diff(concave).max() < 0.025              # at most 2.5 times the truth's step
    np.testing.assert_array_equal(concave[:25] == 0, relaxed[:25] == 0)   # same choice
    # past a fifth of the range the prior is gone: the value is the relaxed lasso's
    np.testing.assert_allclose(concave[40:], relaxed[40:], atol=0.01)
    np.testing.assert_allclose(concave[40:], c[40:, 2], atol=0.01)
    for bad in (1.5, 0, "yes"):
        with pytest.raises(ValueError, match="debias must be"):
            estimate_joint(d, resp, debias=bad)


def test_joint_fit_in_chunks_equals_one_pass(rng, monkeypatch):
    import faceanalysis.estimation.estimators as est

    resp = _response(rng)
    c = rng.uniform(0, 0.6, (40, 4)) * resp.upper
    d = resp.predict(c) + rng.normal(0, 0.01, (40, len(FIDS), 2))
    whole = estimate_joint(d, resp)
    smooth = estimate_joint(d, resp, temporal=0.05)
    monkeypatch.setattr(est, "_CHUNK_ELEMENTS", 4 * 8 * 7)       # 7 frames a chunk
    # (a batch stops iterating when none of its frames gains: a chunk may stop sooner)
    np.testing.assert_allclose(estimate_joint(d, resp), whole, atol=1e-6)
    # the temporal prior's centres are cut into the same chunks as its frames
    np.testing.assert_allclose(estimate_joint(d, resp, temporal=0.05), smooth, atol=1e-6)


def test_a_short_sequence_is_shared_among_threads_with_the_same_result(rng):
    resp = _response(rng)
    c = rng.uniform(0, 0.6, (40, 4)) * resp.upper
    d = resp.predict(c) + rng.normal(0, 0.01, (40, len(FIDS), 2))
    for temporal in (0.0, 0.01):
        np.testing.assert_allclose(estimate_joint(d, resp, threads=2, temporal=temporal),
                                   estimate_joint(d, resp, threads=1, temporal=temporal),
                                   atol=1e-6)


def test_a_second_measurement_enters_the_same_fit(rng):
    # the chin is not seen, so the points alone cannot tell the jaw; a linear measurement
    # of it (as the dense flow gives) in the objective does
    resp = _response(rng)
    c = np.array([[0.3, 0.0, 0.2, 0.15]])
    d = resp.predict(c)
    d[:, FIDS.index("chin")] = np.nan
    a = np.zeros((3, 4))
    a[0, 3] = 2.0                                        # reads the jaw, 2 units per radian
    y = a @ c[0]
    alone = estimate_joint(d, resp, robust=None, sparsity=0)
    both = estimate_joint(d, resp, robust=None, sparsity=0,
                          quadratic=(a.T @ a, (y @ a)[None]))
    assert both[0, 3] == pytest.approx(0.15, abs=0.01)
    assert abs(alone[0, 3] - 0.15) > 0.02 or np.isnan(alone[0, 3])
    no_frame = estimate_joint(d, resp, robust=None, sparsity=0,
                              quadratic=(a.T @ a, np.full((1, 4), np.nan)))
    np.testing.assert_allclose(no_frame, alone)
    with pytest.raises(ValueError, match="quadratic"):
        estimate_joint(d, resp, quadratic=(np.eye(3), np.zeros((1, 3))))


def _twins():
    """Two controls whose points tell them apart only weakly, and a third of their own."""
    levels = np.linspace(0, 1, 6)
    disp = np.zeros((3, 6, 4, 2))
    disp[0, :, 0] = np.outer(levels, [0.1, 0.5])
    disp[0, :, 1] = np.outer(levels, [0.0, 0.3])
    disp[1, :, 0] = np.outer(levels, [0.0, 0.5])
    disp[1, :, 1] = np.outer(levels, [0.05, 0.3])
    disp[2, :, 2] = np.outer(levels, [0.0, 0.6])
    disp[2, :, 3] = np.outer(levels, [0.0, 0.4])
    return FiducialResponse(("levator_labii_l", "levator_labii_nasi_l", "frontalis_inner_l"),
                            ("p0", "p1", "p2", "p3"), np.zeros((4, 2)), disp, np.ones(3),
                            levels)


def test_temporal_prior_keeps_twins_from_trading_places_and_a_step_sharp():
    resp = _twins()
    c = np.zeros((60, 3))
    c[:, :2] = 0.3                                    # both twins held, the third steps
    c[30:, 2] = 0.6
    d = resp.predict(c) + np.random.default_rng(3).normal(0, 0.02, (60, 4, 2))
    alone = estimate_joint(d, resp, robust=None, debias=0.2)
    seq = estimate_joint(d, resp, robust=None, debias=0.2, temporal=0.01)

    def trading(e):
        return np.abs(np.diff(e[:, 0] - e[:, 1])).mean()

    assert trading(seq) < 0.6 * trading(alone)         # 0.21 against 0.38
    # what the points do determine is not smoothed: the twins' sum, the step
    np.testing.assert_allclose(seq[:, :2].sum(axis=1), alone[:, :2].sum(axis=1), atol=0.02)
    assert seq[30, 2] > 0.6 - 0.03 and seq[29, 2] < 0.02
    np.testing.assert_allclose(seq[:, 2], alone[:, 2], atol=0.01)


def test_temporal_prior_needs_both_neighbours():
    resp = _twins()
    c = np.zeros((6, 3))
    c[:, 0] = 0.4
    c[1, 0] = 0.6                                      # off its neighbours' mean
    d = resp.predict(c) + np.random.default_rng(1).normal(0, 0.02, (6, 4, 2))
    d[3] = np.nan                                      # a lost frame
    alone = estimate_joint(d, resp)
    seq = estimate_joint(d, resp, temporal=0.5)
    # the ends, and the frames beside the lost one, have no pair of neighbours to follow
    np.testing.assert_array_equal(seq[[0, 2, 4, 5]], alone[[0, 2, 4, 5]])
    assert np.isnan(seq[3]).all() and not np.array_equal(seq[1], alone[1])
    # two frames (a photograph pair) are fitted as they are
    np.testing.assert_array_equal(estimate_joint(d[:2], resp, temporal=0.5), alone[:2])
    for bad in (-0.1, np.nan, True, "0.01"):
        with pytest.raises(ValueError, match="temporal must be"):
            estimate_joint(d, resp, temporal=bad)


def test_fit_residual_of_a_long_video_is_each_frame_own():
    # more frames than one chunk, with lost frames and unseen points: each frame's RMS
    # distance from the response's prediction, NaN where nothing was seen or estimated
    levels = np.linspace(0, 1, 3)
    disp = np.zeros((2, 3, 3, 2))
    disp[0, :, :, 1] = levels[:, None]
    disp[1, :, 0, 0] = 2 * levels
    resp = FiducialResponse(("a", "b"), ("p", "q", "r"), np.zeros((3, 2)), disp,
                            np.ones(2), levels)
    rng = np.random.default_rng(2)
    n = 1100
    c = rng.uniform(0.0, 1.0, (n, 2))
    d = resp.predict(c) + rng.normal(0.0, 0.1, (n, 3, 2))
    d[700, 1] = np.nan
    d[900] = np.nan
    c[20] = np.nan
    r = fit_residual(d, resp, c)
    for t in (0, 511, 512, 700, 1099):
        e = np.sum((d[t] - resp.predict(c[t])[0]) ** 2, axis=1)
        assert r[t] == pytest.approx(np.sqrt(np.nanmean(e)), rel=1e-12)
    assert np.isnan(r[[20, 900]]).all()
    assert np.isfinite(np.delete(r, [20, 900])).all()


def test_response_prints_its_size_not_its_tables(rng):
    assert repr(_response(rng)) == "<FiducialResponse: 4 controls x 4 points, 6 levels>"
