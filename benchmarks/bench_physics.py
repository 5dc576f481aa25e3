"""Physics face model: spring updates/s, explicit RK2 steps/s, per-frame equilibrium frames/s.

For the default model (resolution 0.4, about 8,300 springs) and for finer meshes of about
20k and 100k springs: biphasic spring-force evaluations per second (Numba kernel, with the
vectorised NumPy version as the peer), explicit second-order Runge-Kutta steps per second
(two full force evaluations each: springs, volume, skull and lips), and frames per second
to per-frame equilibrium when the model is driven by 30 fps expression sequences from
``synth.facs`` (happiness and surprise, 2 s each; the prefactored L-BFGS solver warm-started
from the previous frame at the default tolerance), with the mean iterations per frame and
the median / max error of those equilibria against a tight solve from the same start; at the
default tolerance (3e-4 cm) and at a looser 1e-3 cm.  Everything runs on one core; next to the
wall-clock frames/s, ``cpu_frames_per_s`` gives the rate in CPU time of the process (what one
core delivers when other processes share the machine).
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import time  # noqa: E402

import numpy as np  # noqa: E402
from _harness import Figure, median_time, ratio  # noqa: E402

NAME = "physics"
TARGET_SPRING_UPDATES = 50e6
TARGET_FPS = {"default": 300.0, "100k springs": 30.0}


def _cases(quick: bool):
    from synth.model import DEFAULT_RESOLUTION

    cases = [("default", DEFAULT_RESOLUTION), ("20k springs", 0.68)]
    cases.append(("100k springs", 1.0 if quick else 1.66))
    return cases


def _sequence(n_frames: int):
    import pandas as pd

    from synth.facs import expression_timeline

    parts = [expression_timeline(name, n_frames) for name in ("happiness", "surprise")]
    return pd.concat(parts, ignore_index=True)


def _equilibrium_figures(model, label: str, quick: bool, tol: float = 3e-4) -> list[Figure]:
    from synth.model import FaceModel

    df = _sequence(20 if quick else 60)
    rows = [r for _, r in df.iterrows()]
    times, cpu, iters = [], [], []
    model.reset()
    model.equilibrate()
    for row in rows:
        model.set_contractions(row.to_dict())
        c0 = time.process_time()
        t0 = time.perf_counter()
        model.equilibrate(tol=tol)
        times.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
        iters.append(model.solver.last_iterations)
    fps = len(rows) / float(np.sum(times))
    # accuracy: tight solves from the same starting states, on a subset of frames
    ref = FaceModel(model.mesh)
    errs = []
    model.reset()
    step = (4 if quick else 3) if model.lattice.n_springs < 15000 else 12
    for k, row in enumerate(rows):
        model.set_contractions(row.to_dict())
        if k % step == 0:
            ref._x = model.node_positions
            ref.set_contractions(row.to_dict())
            ref._x = model.node_positions
            exact = ref.equilibrate(tol=1e-7, max_iter=20000)
            model.equilibrate(tol=tol)
            errs.append(float(np.abs(exact - model.surface_vertices).max()))
        else:
            model.equilibrate(tol=tol)
    # CPU time of this (single-threaded) process: the one-core throughput, without the time
    # slices lost to other processes on a shared machine
    extra = {"tol_cm": tol, "iterations_per_frame": float(np.mean(iters)),
             "cpu_frames_per_s": len(rows) / max(float(np.sum(cpu)), 1e-12),
             "median_error_cm": float(np.median(errs)), "max_error_cm": float(np.max(errs)),
             "frames": len(rows), "springs": model.lattice.n_springs}
    metric = "equilibrium frames/s (30 fps expressions)"
    if tol != 3e-4:
        metric += f", tol {tol:g} cm"
    return [Figure(NAME, label, metric, fps, "frames/s", True,
                   target=TARGET_FPS.get(label) if tol == 3e-4 else None, extra=extra)]


def run(quick: bool = False) -> list[Figure]:
    from synth.integrators import DynamicState, rk2_step
    from synth.model import FaceModel
    from synth.springs import spring_forces, spring_forces_numpy

    figures: list[Figure] = []
    repeat = 5 if quick else 11
    for label, res in _cases(quick):
        model = FaceModel.build(resolution=res)
        lat = model.lattice
        x = lat.rest + 0.01 * np.random.default_rng(0).standard_normal(lat.rest.shape)
        out = np.zeros_like(x)
        number = max(1, int(2e6 // lat.n_springs))

        def numba_springs(x=x, out=out, lat=lat):
            out[:] = 0.0
            spring_forces(x, lat, out)

        t_nb = median_time(numba_springs, repeat=repeat, number=number)
        t_np = median_time(lambda x=x, lat=lat: spring_forces_numpy(x, lat), repeat=repeat,
                           number=max(1, number // 10))
        ups = lat.n_springs / t_nb
        figures.append(Figure(NAME, f"{label} ({lat.n_springs} springs)", "spring updates/s",
                              ups, "springs/s", True, target=TARGET_SPRING_UPDATES,
                              peer="NumPy (vectorised)",
                              ratio=ratio(ups, lat.n_springs / t_np, higher_is_better=True),
                              extra={"numpy_springs_per_s": lat.n_springs / t_np}))
        # explicit RK2 steps (two evaluations of every force term each)
        model.set_contractions({"zygomaticus_major_l": 0.5})
        state = DynamicState(model.node_positions)
        dt = model.stable_dt
        damping = model.damping
        n_steps = max(1, int(2e5 // lat.n_springs))

        def steps(state=state, model=model, dt=dt, damping=damping, n=n_steps):
            for _ in range(n):
                rk2_step(model.system, state, dt, damping)

        t_step = median_time(steps, repeat=repeat) / n_steps
        figures.append(Figure(NAME, f"{label} ({lat.n_springs} springs)", "explicit RK2 steps/s",
                              1.0 / t_step, "steps/s", True,
                              extra={"dt_s": dt, "simulated_s_per_wall_s": dt / t_step}))
        for tol in (3e-4, 1e-3):
            model.reset()
            for f in _equilibrium_figures(model, label, quick, tol):
                f.case = f"{label} ({lat.n_springs} springs)"
                figures.append(f)
    return figures
