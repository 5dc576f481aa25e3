"""Snakes: trackers.ContourSystem vs skimage.segmentation.active_contour, same image and energy.

The scikit-image gallery case: ``data.astronaut()`` in grey, Gaussian sigma 3, a
400-point circle around the head (periodic), plus a 100-point open contour (the
upper half of the same circle, ends fixed). Both solvers get the same image
energy: scikit-image's ``w_edge * sobel(image)`` is handed to ours as the
potential ``P = -255 * sobel(image)`` (8-bit units), and its internal energy
(``alpha`` membrane, ``beta`` thin plate, step ``gamma``) maps onto eqs. 7-11 as
tension ``a = alpha`` with zero rest lengths and ``nu = 0``, rigidity ``b = beta``,
``p = 1/255`` and the linear part of the tension in the factored matrix
(``tension='split'``; with zero rest lengths that is exactly scikit-image's implicit
membrane). scikit-image keeps its explicit image force stable by capping moves at
``max_px_move = 1`` px; ours has no cap, so it takes ``gamma/dt = 0.01`` (ten times
the gallery's ``gamma = 0.001``), which changes the path but not the equilibrium
(the balance of internal and image forces does not involve ``gamma``).

Figures: time per iteration (setup excluded: difference of two run lengths),
time and iterations to equilibrium (each solver's own stopping rule: scikit-image's
default ``convergence=0.1``, ours a movement threshold of 0.01 px per step), and the
final contour's mean distance to the reference edge (Canny edges of the grey image
with sigma 3, distance transform sampled bilinearly at the nodes).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from _harness import Figure, median_time, ratio  # noqa: E402

from trackers.sampling import force_field, sample_bilinear  # noqa: E402
from trackers.snake_types import Contour, SnakeParams  # noqa: E402
from trackers.snakes import ContourSystem  # noqa: E402

ALPHA, BETA, GAMMA = 0.015, 10.0, 0.001  # the gallery's values
OUR_GAMMA = 0.01  # see the module docstring


def _setup():
    from scipy.ndimage import distance_transform_edt
    from skimage import data
    from skimage.color import rgb2gray
    from skimage.feature import canny
    from skimage.filters import gaussian, sobel

    grey = rgb2gray(data.astronaut())
    smooth = gaussian(grey, sigma=3, preserve_range=False)
    potential = (-255.0 * sobel(smooth)).astype(np.float32)
    edges = canny(grey, sigma=3)
    dist = distance_transform_edt(~edges)
    s = np.linspace(0, 2 * np.pi, 400)
    circle_rc = np.c_[100 + 100 * np.sin(s), 220 + 100 * np.cos(s)]
    s_open = np.linspace(np.pi, 2 * np.pi, 100)
    arc_rc = np.c_[100 + 100 * np.sin(s_open), 220 + 100 * np.cos(s_open)]
    return smooth, potential, dist, circle_rc, arc_rc


def _ours(init_rc, closed):
    params = SnakeParams(gamma=OUR_GAMMA, dt=1.0, a=ALPHA, b=BETA, nu=0.0, p=1.0 / 255.0)
    return ContourSystem([Contour(init_rc[:, ::-1].copy(), closed=closed,
                                  fixed_ends=not closed, rest_lengths=0.0)], params,
                         tension="split")


def _skimage(smooth, init_rc, closed, n, convergence):
    from skimage.segmentation import active_contour
    return active_contour(smooth, init_rc, alpha=ALPHA, beta=BETA, gamma=GAMMA,
                          max_num_iter=n, convergence=convergence,
                          boundary_condition="periodic" if closed else "fixed")


def _mean_dist(dist, xy):
    xy = np.clip(xy, 0, [dist.shape[1] - 1, dist.shape[0] - 1])
    return float(sample_bilinear(dist, xy).mean())


def run(quick: bool = False) -> list[Figure]:
    smooth, potential, dist, circle_rc, arc_rc = _setup()
    F = force_field(potential)  # -grad P, p applied per node
    repeat = 3 if quick else 7
    figures = []
    for case, init_rc, closed in (("circle 400 pts", circle_rc, True),
                                  ("open 100 pts", arc_rc, False)):
        # --- time per iteration (setup excluded) ---
        n1, n2 = (20, 120) if quick else (50, 300)
        sk1 = median_time(lambda i=init_rc, c=closed, n=n1: _skimage(smooth, i, c, n, 0.0),
                          repeat=repeat)
        sk2 = median_time(lambda i=init_rc, c=closed, n=n2: _skimage(smooth, i, c, n, 0.0),
                          repeat=repeat)
        sk_it = max(sk2 - sk1, 1e-12) / (n2 - n1)
        m1, m2 = 2000, 12000
        system = _ours(init_rc, closed)
        t1 = median_time(lambda s=system, m=m1: s.step(F, m), repeat=repeat)
        system = _ours(init_rc, closed)
        t2 = median_time(lambda s=system, m=m2: s.step(F, m), repeat=repeat)
        our_it = max(t2 - t1, 1e-12) / (m2 - m1)
        figures.append(Figure("snakes", case, "time per iteration", our_it * 1e6, "us",
                              higher_is_better=False, target=sk_it * 1e6 / 50,
                              peer="skimage.active_contour",
                              ratio=ratio(our_it, sk_it, higher_is_better=False),
                              extra={"peer_value": sk_it * 1e6}))
        # --- time to equilibrium and accuracy ---
        out = {}

        def sk_run(i=init_rc, c=closed, out=out):
            out["sk"] = _skimage(smooth, i, c, 2500, 0.1)

        sk_eq = median_time(sk_run, repeat=max(repeat // 2, 2), warmup=0)

        def our_run(i=init_rc, c=closed, out=out):
            s = _ours(i, c)
            out["res"] = s.relax(F, tol=0.01, max_iter=20000)
            out["ours"] = s.positions

        our_eq = median_time(our_run, repeat=repeat)
        sk_xy = out["sk"][:, ::-1]
        figures.append(Figure("snakes", case, "time to equilibrium", our_eq * 1e3, "ms",
                              higher_is_better=False, peer="skimage.active_contour",
                              ratio=ratio(our_eq, sk_eq, higher_is_better=False),
                              extra={"peer_value": sk_eq * 1e3,
                                     "iterations": out["res"].iterations,
                                     "converged": out["res"].converged}))
        d_ours = _mean_dist(dist, out["ours"])
        d_sk = _mean_dist(dist, sk_xy)
        figures.append(Figure("snakes", case, "mean distance to reference edge", d_ours, "px",
                              higher_is_better=False, target=d_sk,
                              peer="skimage.active_contour",
                              ratio=ratio(d_ours, d_sk, higher_is_better=False),
                              extra={"peer_value": d_sk}))
    return figures


if __name__ == "__main__":
    from _harness import emit

    emit("snakes", run(quick="--quick" in sys.argv))
