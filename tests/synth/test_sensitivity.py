"""The equilibrium's sensitivity to the controls (``synth.sensitivity``)."""

import numpy as np
import pytest

from synth.sensitivity import JAW, equilibrium_sensitivity, stiffness_factor, tangent_stiffness


@pytest.fixture(scope="module")
def model():
    from synth.model import FaceModel

    m = FaceModel.default()
    m.set_contractions({"zygomaticus_major_l": 0.6, "frontalis_major_r": 0.3,
                        "orbicularis_oris": 0.2}, jaw_rotation=0.1)
    m.equilibrate(tol=1e-8, max_iter=50000)
    return m


def _equilibrium(model, values, jaw):
    model.set_contractions(values, jaw_rotation=jaw)
    model.equilibrate(tol=1e-8, max_iter=50000)
    return model.node_positions


def test_stiffness_matches_dense_differences_of_the_forces(model):
    system, x = model.system, model.node_positions
    k = tangent_stiffness(system, x)
    free = system.free
    rng = np.random.default_rng(0)
    f0 = system.forces(x)[0][free].ravel()
    for col in rng.choice(3 * len(free), 6, replace=False):
        xx = x.copy()
        node, axis = free[col // 3], col % 3
        h = 1e-6
        xx[node, axis] += h
        dense = -(system.forces(xx)[0][free].ravel() - f0) / h
        column = k[:, col].toarray().ravel()
        # symmetrised: the column is the mean of the force differences' and its transpose's
        assert np.abs(column - dense).max() <= 1e-3 * np.abs(dense).max()
    # the lattice at an equilibrium resists every motion of its free nodes
    assert (k.diagonal() > 0).all()


@pytest.mark.parametrize("name", ["zygomaticus_major_l", "orbicularis_oris", JAW])
def test_sensitivity_matches_differenced_equilibria(model, name):
    base = dict(model.contractions)
    jaw = model.jaw_rotation
    x0 = model.node_positions
    try:
        dx = equilibrium_sensitivity(model, [name])[0]
        h = 0.005
        moved = []
        for sign in (1, -1):
            values, j = dict(base), jaw
            if name == JAW:
                j = jaw + sign * h
            else:
                values[name] += sign * h
            moved.append(_equilibrium(model, values, j))
        fd = (moved[0] - moved[1]) / (2 * h)
        assert np.linalg.norm(dx - fd) <= 0.01 * np.linalg.norm(fd)
    finally:
        _equilibrium(model, base, jaw)
    assert np.abs(model.node_positions - x0).max() < 1e-5


def test_sensitivity_leaves_the_model_as_it_was(model):
    x0, jaw, f_ext = model.node_positions, model.system.jaw_rotation, model.system.f_ext.copy()
    factor = stiffness_factor(model.system, x0)
    a = equilibrium_sensitivity(model, ["risorius_l", JAW], factor=factor)
    b = equilibrium_sensitivity(model, ["risorius_l", JAW])
    np.testing.assert_allclose(a, b)
    assert np.array_equal(model.node_positions, x0)
    assert model.system.jaw_rotation == jaw and np.array_equal(model.system.f_ext, f_ext)
    # only the jaw moves fixed nodes
    fixed = model.lattice.fixed
    assert np.abs(a[0][fixed]).max() == 0 and np.abs(a[1][fixed]).max() > 0


def test_unknown_controls_and_bad_arguments_are_refused(model):
    with pytest.raises(ValueError, match="unknown controls.*zygomaticus_major_l"):
        equilibrium_sensitivity(model, ["smile"])
    with pytest.raises(ValueError, match="step"):
        tangent_stiffness(model.system, model.node_positions, step=0)
    with pytest.raises(ValueError, match="x must have shape"):
        tangent_stiffness(model.system, model.node_positions[:10])
