"""The `mesh` fit's step solver: projected Newton against FISTA on the same bounded quadratics.

Each Gauss-Newton step of the `mesh` fit (the default estimator) is a bounded quadratic in the
26 controls, Jacobi-scaled (``box_qp(precondition=True)``). The steps are collected from the
default analysis of a clip (``../shared/data/real/WolfgangLanger_Pexels.mp4`` when present,
else a rendered 640x360 happiness sequence) and solved again on one core: by the projected
Newton steps ``box_qp`` takes, and by FISTA on the same scaled problems at the 400 iterations
the fit used to give them (the peer) and at 20,000. Per step, the reference is whichever of
the 20,000 iterations and the Newton steps reaches the lower objective (FISTA's stop, no
variable moving by 1e-9, can halt it short of the optimum along a flat direction). Printed:
each solver's time per step, its largest distance from the reference (a fraction of the
control's range) and the share of the steps whose objective lies within a billionth of its
fall from the reference's (the fall from the start point 0, at least a billionth of the
largest its linear term could give); then the whole fit of the same clip on one thread.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import logging  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
from _harness import Figure, median_time, ratio  # noqa: E402

NAME = "fit"
DATA = Path(os.environ.get("FACEANALYSIS_SHARED_DATA",
                           Path(__file__).resolve().parents[2] / "shared" / "data"))
CLIP = Path(os.environ.get("FACEANALYSIS_REAL_DATA", DATA / "real")) / "WolfgangLanger_Pexels.mp4"


def _collect(video, end):
    """The clip's default analysis, with every bounded quadratic of its ``mesh`` fit and the
    fit's own inputs: (hess, grad0, lo, hi), (displacements, response, options)."""
    from faceanalysis.analysis.pipeline import analyze
    from faceanalysis.estimation import estimators, registry

    steps, fit = [], {}
    solve, mesh_fit = estimators.box_qp, registry.mesh_fit

    def keep_step(hess, grad0, lo, hi, **options):
        # the fit's own steps, not the identifiability simulation's (which comes after it)
        if options.get("precondition", True) and "d" not in fit:
            steps.append(tuple(np.broadcast_to(a, grad0.shape).copy() if a.ndim < 3 else a.copy()
                               for a in (hess, grad0, np.asarray(lo), np.asarray(hi))))
        return solve(hess, grad0, lo, hi, **options)

    def keep_fit(displacements, response, **options):
        out = mesh_fit(displacements, response, **options)
        fit.update(d=displacements, response=response, options=options)
        return out

    estimators.box_qp, registry.mesh_fit = keep_step, keep_fit
    try:
        analyze(video, end=end)
    finally:
        estimators.box_qp, registry.mesh_fit = solve, mesh_fit
    return tuple(np.concatenate([s[i] for s in steps]) for i in range(4)), fit


def _fista(hess, grad0, lo, hi, iterations):
    """FISTA on the Jacobi-scaled problems, as ``box_qp`` solved them before its Newton steps."""
    from faceanalysis.estimation.estimators import _fista_nb, _jacobi_scales

    d = _jacobi_scales(hess)
    scaled = np.ascontiguousarray(hess / d[:, :, None] / d[:, None, :])
    lipschitz = np.maximum(np.sqrt(np.einsum("tij,tij->t", scaled, scaled)), 1e-300)
    y = np.zeros_like(grad0)
    _fista_nb(scaled, np.ascontiguousarray(grad0 / d), np.ascontiguousarray(lo * d),
              np.ascontiguousarray(hi * d), lipschitz, int(iterations), 1e-9 * d.min(axis=1), y)
    return np.clip(y / d, lo, hi)


def run(quick: bool = False) -> list[Figure]:
    from faceanalysis.estimation.estimators import box_qp
    from faceanalysis.estimation.registry import mesh_fit

    logging.disable(logging.WARNING)
    with tempfile.TemporaryDirectory() as tmp:
        if CLIP.is_file():
            case, video, end = "real WolfgangLanger 640x360", CLIP, 160 if quick else None
        else:
            from synth.render.sequence import render_sequence

            print(f"# {CLIP} is absent: a rendered sequence instead", file=sys.stderr)
            files = render_sequence(Path(tmp) / "seq", expression="happiness",
                                    frames=40 if quick else 120, size=(640, 360), seed=11,
                                    head_motion=0.3, noise=2.0, flow=False)
            case, video, end = "synthetic 640x360 happiness", Path(files["video"]), None
        (hess, grad0, lo, hi), fit = _collect(video, end)
    logging.disable(logging.NOTSET)
    n = len(grad0)
    span = np.maximum(hi - lo, 1e-12)

    def objective(x):
        return 0.5 * np.einsum("ti,tij,tj->t", x, hess, x) - np.einsum("ti,ti->t", grad0, x)

    newton = box_qp(hess, grad0, lo, hi, iterations=400)
    fista = _fista(hess, grad0, lo, hi, 400)
    long = _fista(hess, grad0, lo, hi, 20_000)
    reference = np.where((objective(newton) < objective(long))[:, None], newton, long)
    # the objective's fall from the start point 0 (objective 0), at least a billionth of the
    # largest fall the linear term alone could give: a fall of rounding's size is no fall
    fall = np.maximum(-objective(reference), 1e-9 * np.sum(np.abs(grad0) * span, axis=1))
    repeat = 3 if quick else 5
    newton_s = median_time(lambda: box_qp(hess, grad0, lo, hi, iterations=400), repeat=repeat)
    fista_s = median_time(lambda: _fista(hess, grad0, lo, hi, 400), repeat=repeat)
    figures = []
    for label, x, seconds in (("projected Newton", newton, newton_s),
                              ("FISTA, 400 iterations", fista, fista_s)):
        peer = label != "FISTA, 400 iterations"
        distance = np.max(np.abs(x - reference) / span, axis=1)
        excess = (objective(x) - objective(reference)) / fall
        figures.append(Figure(
            NAME, case, f"{label}: time per step", 1e6 * seconds / n, "us", False,
            peer="FISTA, 400 iterations" if peer else None,
            ratio=ratio(seconds, fista_s, higher_is_better=False) if peer else None,
            extra={"steps": n}))
        figures.append(Figure(
            NAME, case, f"{label}: largest distance from the reference", float(distance.max()),
            "of a range", False, extra={"p99": float(np.quantile(distance, 0.99))}))
        figures.append(Figure(
            NAME, case, f"{label}: objective within 1e-9 of its fall from the reference's",
            float(np.mean(excess <= 1e-9)), "of the steps", True,
            extra={"p99": float(np.quantile(excess, 0.99))}))
    whole = median_time(lambda: mesh_fit(fit["d"], fit["response"],
                                         **{**fit["options"], "threads": 1}),
                        repeat=1 if quick else 3)
    frames = int(np.isfinite(fit["d"]).all(axis=2).any(axis=1).sum())
    figures.append(Figure(NAME, case, "the mesh fit on one thread", whole, "s", False,
                          extra={"frames": frames, "steps": n}))
    return figures
