"""Explicit RK2 / Verlet dynamics and the prefactored equilibrium solver."""

from __future__ import annotations

import numpy as np
import pytest

from synth.forces import TissueSystem
from synth.integrators import (
    DynamicState,
    EquilibriumSolver,
    SimulationError,
    damping_coefficients,
    rk2_step,
    stable_timestep,
    verlet_step,
)
from synth.lattice import build_lattice

from .physics_standin import make_standin_mesh


@pytest.fixture(scope="module")
def lattice():
    return build_lattice(make_standin_mesh(nx=11, ny=13))


def _loaded_system(lattice, scale=2.0, jaw=0.0):
    system = TissueSystem(lattice)
    fascia = lattice.layer_nodes("fascia")
    f = np.zeros_like(lattice.rest)
    centre = lattice.rest[lattice.n_vertices // 2 + 3]
    w = np.exp(-np.sum((lattice.rest[fascia] - centre) ** 2, axis=1) / 4.0)
    f[fascia] = scale * w[:, None] * np.array([0.6, 0.8, 0.0])
    system.set_external(f)
    system.set_jaw(jaw)
    return system


def test_zero_load_stays_at_rest(lattice):
    system = TissueSystem(lattice)
    x = EquilibriumSolver(system).solve(lattice.rest)
    assert np.abs(x - lattice.rest).max() < 1e-12
    state = DynamicState(lattice.rest)
    g = damping_coefficients(lattice)
    for _ in range(20):
        rk2_step(system, state, stable_timestep(lattice, g), g)
    assert np.abs(state.x - lattice.rest).max() < 1e-12


def test_equilibrium_has_small_residual(lattice):
    system = _loaded_system(lattice)
    x = EquilibriumSolver(system).solve(lattice.rest, tol=1e-7)
    f, _ = system.forces(x)
    load = np.abs(system.f_ext).max()
    assert np.abs(f[system.free]).max() < 1e-3 * load
    assert np.abs(x - lattice.rest).max() > 0.05


def test_energy_decreases_under_damping(lattice):
    system = _loaded_system(lattice)
    g = damping_coefficients(lattice)
    dt = stable_timestep(lattice, g)
    state = DynamicState(lattice.rest)
    m = lattice.mass
    total = []
    for _ in range(300):
        rk2_step(system, state, dt, g)
        _, pot = system.forces(state.x)
        total.append(pot + 0.5 * np.sum(m[:, None] * state.v**2))
    total = np.array(total)
    assert np.all(np.diff(total) <= 1e-9 * np.abs(total).max())
    assert total[-1] < total[0]


@pytest.mark.parametrize("stepper", [rk2_step, verlet_step])
def test_explicit_and_implicit_agree_at_equilibrium(lattice, stepper):
    system = _loaded_system(lattice, jaw=0.15)
    x_imp = EquilibriumSolver(system).solve(lattice.rest, tol=1e-8, max_iter=5000)
    g = damping_coefficients(lattice)
    dt = stable_timestep(lattice, g)
    state = DynamicState(lattice.rest)
    system.apply_boundary(state.x)
    for _ in range(400):
        start = state.x.copy()
        for _ in range(100):
            stepper(system, state, dt, g)
        if np.abs(state.x - start).max() < 1e-8:
            break
    assert np.abs(state.x - x_imp).max() < 1e-4


def test_warm_start_converges_faster(lattice):
    system = _loaded_system(lattice)
    solver = EquilibriumSolver(system)
    x1 = solver.solve(lattice.rest, tol=1e-6)
    cold = solver.last_iterations
    system.set_external(system.f_ext * 1.05)
    solver.solve(x1, tol=1e-6)
    assert solver.last_iterations < cold


def test_blow_up_raises_naming_parameters(lattice):
    system = _loaded_system(lattice)
    g = damping_coefficients(lattice)
    state = DynamicState(lattice.rest)
    with pytest.raises(SimulationError, match=r"dt=.*stable_timestep"):
        for _ in range(200):
            rk2_step(system, state, 50 * stable_timestep(lattice, g), g)


def test_non_finite_input_raises(lattice):
    system = _loaded_system(lattice)
    x = lattice.rest.copy()
    x[system.free[5]] = np.nan
    g = damping_coefficients(lattice)
    with pytest.raises(SimulationError, match="non-finite"):
        rk2_step(system, DynamicState(x), stable_timestep(lattice, g), g)


def test_solver_iteration_cap_raises(lattice):
    system = _loaded_system(lattice)
    with pytest.raises(SimulationError, match="max_iter=2"):
        EquilibriumSolver(system).solve(lattice.rest, tol=1e-12, max_iter=2)


@pytest.mark.parametrize("bad", [0.0, -1.0, np.nan])
def test_bad_dt(lattice, bad):
    system = _loaded_system(lattice)
    g = damping_coefficients(lattice)
    with pytest.raises(ValueError, match="dt"):
        rk2_step(system, DynamicState(lattice.rest), bad, g)


def test_solver_parameter_validation(lattice):
    system = TissueSystem(lattice)
    with pytest.raises(ValueError, match="history"):
        EquilibriumSolver(system, history=-1)
    with pytest.raises(ValueError, match="tol"):
        EquilibriumSolver(system).solve(lattice.rest, tol=0.0)
