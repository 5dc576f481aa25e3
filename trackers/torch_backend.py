"""Batched torch/kornia backend: potentials and snake relaxation for many images at once.

The NumPy/Numba backend (:mod:`trackers.potentials`, :mod:`trackers.snakes`) works on
one image and one contour system at a time, in compiled loops. This module does the
same arithmetic as batched tensor operations over a leading batch dimension ``B`` (many
videos, or many frames), on any torch device:

:func:`potential_batch`
    ``images[B, 1, H, W] -> P[B, 1, H, W]``: the edge (eq. 13), valley and dark-below
    potentials of :mod:`trackers.potentials`, with :func:`kornia.filters.gaussian_blur2d`
    (on a symmetric padding, OpenCV's ``BORDER_REFLECT``) and
    :func:`kornia.filters.spatial_gradient`; borders use the same one-sided differences.
:func:`force_field_batch`
    ``P[B, C, H, W] -> F[B, C, 2, H, W]``, ``-grad P`` as :func:`trackers.sampling.force_field`.
:func:`sample_bilinear_batch`
    ``field[B, C, H, W]`` at ``points[B, N, 2] -> [B, N, C]`` through
    :func:`torch.nn.functional.grid_sample` (``align_corners=True``; image pixels, x
    right, y down, origin at the centre of the top-left pixel; NaN outside).
:class:`TorchContourSystem`
    B contour systems (one :class:`~trackers.snakes.ContourSystem` each, or one repeated)
    relaxed together with the semi-implicit update of eq. 11 exactly as
    ``trackers.snakes`` does it: explicit tension (or ``tension='split'``), viscoelastic
    rest lengths clamped at 0, normal-only image forces, the per-step move cap, fixed-end
    anchors, closed contours, per-contour fields and strengths, and the same equilibrium
    test ('max' or 'rms' move below ``tol``, ``min_iter``/``max_iter``). The constant
    matrix ``gamma/dt I + K`` is inverted **once** per system, contour by contour (it is
    block-diagonal: contours are decoupled), in float64; every step is then one batched
    matrix product ``(B, K, M, M) @ (B, K, M, 2)`` (``M`` = most nodes in a contour).
    Each batch element stops at its own equilibrium (it is frozen while the others go
    on), so a batched relaxation equals the one-by-one relaxations.
:func:`snake_relax_batch`
    Functional form for one contour per batch element.
:func:`make_tracker` / :class:`TorchTracker`
    ``make_tracker(layout, backend="torch", device="cpu")`` gives a
    :class:`~trackers.tracking.Tracker` whose relaxations run on the torch backend (same
    ``track`` / ``run`` / :class:`~trackers.tracking.TrackResult`); :class:`TorchTracker`
    tracks B videos frame by frame and batches their relaxations into one tensor problem.
    Potentials of the tracker stay the NumPy per-contour boxes (small crops, cheap).

torch and kornia are the optional ``[torch]`` extra; they are imported on first use, so
``import trackers`` and this module never need them. Default precision: float64 on the
CPU (the equivalence tests: contours within 0.05 px of the NumPy backend, in practice
1e-8 px), float32 on other devices.

Where it pays (``python benchmarks/run.py backend``). On a CPU the Numba kernels win:
a relaxation step costs a few hundred tensor operations' overhead for one video and
about 1 us per node for many (the compiled loop: ~60 ns), and OpenCV's float32 blur
beats kornia's convolutions; on a busy two-core machine the torch CPU backend relaxed
contours 10 (64 videos) to 100 (one video) times slower and tracked at 0.2-0.7 times
the frame rate. The backend is meant for a GPU, where a step of any batch size costs
about the same few hundred kernel launches; that case was not measured here.

Why one module of over 1,300 lines: it is one optional backend that mirrors the NumPy one
function by function (the potentials of :mod:`trackers.potentials`, the relaxation of
:mod:`trackers.snakes`, the tracker of :mod:`trackers.tracking`), so that a change to the
arithmetic there has one place to be mirrored in here; its parts share the lazy import of
torch (:func:`require_torch`), the device and dtype rules and ``__doctest_requires__``, and
it is tested as one unit against the NumPy backend. Split, it would scatter one mirror over
several files that only run where the ``[torch]`` extra is installed.
"""

from __future__ import annotations

import threading
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from trackers.snake_types import Contour, RelaxResult, SnakeParams
from trackers.snakes import ContourSystem

__all__ = [
    "BACKENDS",
    "check_backend",
    "TorchContourSystem",
    "TorchTracker",
    "BatchRelaxResult",
    "force_field_batch",
    "make_tracker",
    "potential_batch",
    "require_torch",
    "sample_bilinear_batch",
    "snake_relax_batch",
]

BACKENDS = ("numpy", "torch")
_MISSING = "the torch backend needs the [torch] extra: pip install torch==2.13.0 kornia"
_KINDS = ("edge", "valley", "dark_below")

#: The doctests that need the [torch] extra (names in this module, fnmatch patterns; a
#: class's name covers its methods). The repository's ``conftest.py`` skips them where
#: torch or kornia is not installed; pytest-doctestplus reads the same attribute.
__doctest_requires__ = {
    ("require_torch", "potential_batch", "force_field_batch", "sample_bilinear_batch",
     "TorchContourSystem", "snake_relax_batch", "TorchTracker"): ("torch", "kornia"),
}


def require_torch():
    """Import and return ``(torch, kornia)``, or raise an ImportError naming the extra.

    Examples
    --------
    >>> torch, kornia = require_torch()
    >>> torch.float64.is_floating_point, hasattr(kornia, "filters")
    (True, True)
    """
    try:
        import kornia
        import torch
    except ImportError as exc:
        raise ImportError(_MISSING) from exc
    return torch, kornia


def _device_dtype(device, dtype):
    torch, _ = require_torch()
    try:
        dev = torch.device("cpu" if device is None else device)
    except (RuntimeError, TypeError) as exc:
        raise ValueError(f"device must be 'cpu', 'cuda', 'cuda:N' or a torch.device, got "
                         f"{device!r} ({exc})") from None
    if dev.type == "cuda" and not torch.cuda.is_available():
        raise ValueError(f"device {device!r} asked for but this torch build has no CUDA "
                         f"device available (torch {torch.__version__})")
    if dtype is None:
        dtype = torch.float64 if dev.type == "cpu" else torch.float32
    if dtype not in (torch.float32, torch.float64):
        raise ValueError(f"dtype must be torch.float32 or torch.float64, got {dtype}")
    return dev, dtype


def _check_tensor(x, name, ndim, dims):
    torch, _ = require_torch()
    if not isinstance(x, torch.Tensor):
        raise ValueError(f"{name} must be a torch.Tensor of shape [{', '.join(dims)}], got "
                         f"{type(x).__name__}")
    if x.ndim != ndim:
        raise ValueError(f"{name} must have shape [{', '.join(dims)}], got "
                         f"{list(x.shape)}")
    if not x.is_floating_point():
        raise ValueError(f"{name} must be a floating-point tensor, got {x.dtype}")


# --------------------------------------------------------------------- potentials

def _reflect_index(n, r, device):
    """Indices of a symmetric (OpenCV BORDER_REFLECT, 'fedcba|abcdef') padding by r."""
    torch, _ = require_torch()
    i = torch.arange(-r, n + r, device=device) % (2 * n)
    return torch.where(i < n, i, 2 * n - 1 - i)


def _blur(images, sigma):
    torch, kornia = require_torch()
    r = int(np.ceil(3.0 * sigma))
    k = 2 * r + 1
    H, W = images.shape[-2:]
    padded = images.index_select(-2, _reflect_index(H, r, images.device))
    padded = padded.index_select(-1, _reflect_index(W, r, images.device))
    out = kornia.filters.gaussian_blur2d(padded, (k, k), (float(sigma), float(sigma)),
                                         border_type="constant")
    return out[..., r:r + H, r:r + W]


def _gradient(g):
    """(d/dx, d/dy) with kornia's central differences, one-sided on the image border."""
    _, kornia = require_torch()
    grad = kornia.filters.spatial_gradient(g, mode="diff", order=1, normalized=True)
    gx, gy = grad[:, :, 0], grad[:, :, 1]
    gx[..., 0] = g[..., 1] - g[..., 0]
    gx[..., -1] = g[..., -1] - g[..., -2]
    gy[..., 0, :] = g[..., 1, :] - g[..., 0, :]
    gy[..., -1, :] = g[..., -1, :] - g[..., -2, :]
    return gx, gy


def _diff_x(g):
    """d/dx by central differences, one-sided on the first and last column."""
    torch, _ = require_torch()
    gx = torch.empty_like(g)
    gx[..., 1:-1] = 0.5 * (g[..., 2:] - g[..., :-2])
    gx[..., 0] = g[..., 1] - g[..., 0]
    gx[..., -1] = g[..., -1] - g[..., -2]
    return gx


def _diff_y(g):
    torch, _ = require_torch()
    gy = torch.empty_like(g)
    gy[..., 1:-1, :] = 0.5 * (g[..., 2:, :] - g[..., :-2, :])
    gy[..., 0, :] = g[..., 1, :] - g[..., 0, :]
    gy[..., -1, :] = g[..., -1, :] - g[..., -2, :]
    return gy


def potential_batch(images, kind: str = "edge", sigma: float = 2.0):
    """Image potentials of a batch of grey images (kornia filters).

    The batched counterpart of :func:`trackers.potentials.potential_from_gray` for
    ``kind`` in {'edge', 'valley', 'dark_below'}: Gaussian blur with OpenCV's kernel
    (size ``2 ceil(3 sigma) + 1``) on a symmetric padding, then the same finite
    differences (central inside, one-sided on the image border).

    Parameters
    ----------
    images : Tensor [B, 1, H, W], float
        Grey images in 8-bit units (as :func:`trackers.potentials.to_gray` gives),
        H, W >= 3.
    kind : {'edge', 'valley', 'dark_below'}
    sigma : float
        Gaussian width in pixels.

    Returns
    -------
    P : Tensor [B, 1, H, W]
        Same dtype and device as ``images``.

    Examples
    --------
    >>> import torch
    >>> img = torch.zeros(2, 1, 32, 32, dtype=torch.float64); img[..., 16:] = 255.0
    >>> P = potential_batch(img, "edge", 1.5)
    >>> P.shape, int(P[0, 0, 16].argmin())
    (torch.Size([2, 1, 32, 32]), 15)
    """
    torch, _ = require_torch()
    _check_tensor(images, "images", 4, ("B", "1", "H", "W"))
    if images.shape[1] != 1:
        raise ValueError(f"images must have shape [B, 1, H, W] (grey, one channel), got "
                         f"{list(images.shape)}")
    if images.shape[2] < 3 or images.shape[3] < 3:
        raise ValueError(f"images must be at least 3x3 pixels (H, W), got "
                         f"{list(images.shape)}")
    if kind not in _KINDS:
        raise ValueError(f"kind must be one of {_KINDS}, got {kind!r}")
    sigma = float(sigma)
    if not np.isfinite(sigma) or sigma <= 0:
        raise ValueError(f"sigma must be a positive number, got {sigma}")
    g = _blur(images, sigma)
    if kind == "edge":
        gx, gy = _gradient(g)
        return -torch.sqrt(gx * gx + gy * gy)
    if kind == "dark_below":
        return torch.clamp(_diff_y(g), max=0.0)
    gx = _diff_x(g)
    gxy = _diff_y(gx)
    gxx = torch.zeros_like(g)
    gyy = torch.zeros_like(g)
    gxx[..., 1:-1] = g[..., 2:] - 2.0 * g[..., 1:-1] + g[..., :-2]
    gyy[..., 1:-1, :] = g[..., 2:, :] - 2.0 * g[..., 1:-1, :] + g[..., :-2, :]
    d = 0.5 * (gxx - gyy)
    lam = 0.5 * (gxx + gyy) + torch.sqrt(d * d + gxy * gxy)
    return -(sigma * sigma) * torch.clamp(lam, min=0.0)


def force_field_batch(potentials, *, sizes=None):
    """Image force ``-grad P`` of a batch of potential stacks (central differences).

    Parameters
    ----------
    potentials : Tensor [B, C, H, W]
        C potentials per batch element (e.g. one per contour).
    sizes : Tensor or array_like [B, C, 2] of int (h, w), optional
        Valid size of each field when smaller fields were zero-padded to (H, W): the
        differences are then one-sided on each field's own last row / column, as
        :func:`trackers.sampling.force_field` on the unpadded field.

    Returns
    -------
    F : Tensor [B, C, 2, H, W]
        ``F[:, :, 0]`` the x component, ``F[:, :, 1]`` the y one.

    Examples
    --------
    >>> import torch
    >>> P = -torch.exp(-(torch.arange(9.0) - 4) ** 2).expand(1, 1, 5, 9)
    >>> F = force_field_batch(P)
    >>> bool(F[0, 0, 0, 2, 2] > 0 and F[0, 0, 0, 2, 6] < 0)
    True
    """
    torch, _ = require_torch()
    _check_tensor(potentials, "potentials", 4, ("B", "C", "H", "W"))
    B, C, H, W = potentials.shape
    if H < 2 or W < 2:
        raise ValueError(f"potentials must be at least 2x2 (H, W), got {list(potentials.shape)}")
    dev = potentials.device
    if sizes is None:
        hv = torch.full((B, C, 1, 1), H, device=dev, dtype=torch.long)
        wv = torch.full((B, C, 1, 1), W, device=dev, dtype=torch.long)
    else:
        sz = torch.as_tensor(np.asarray(sizes) if not isinstance(sizes, torch.Tensor)
                             else sizes, device=dev).long()
        if sz.shape != (B, C, 2):
            raise ValueError(f"sizes must have shape [B, C, 2] = [{B}, {C}, 2], got "
                             f"{list(sz.shape)}")
        if (sz[..., 0] < 2).any() or (sz[..., 1] < 2).any() or (sz[..., 0] > H).any() \
                or (sz[..., 1] > W).any():
            raise ValueError(f"sizes must lie in [2, {H}] x [2, {W}]")
        hv = sz[..., 0, None, None]
        wv = sz[..., 1, None, None]
    xs = torch.arange(W, device=dev).view(1, 1, 1, W)
    ys = torch.arange(H, device=dev).view(1, 1, H, 1)
    xs = torch.minimum(xs, wv - 1)  # padding (beyond a field's size) copies its border
    ys = torch.minimum(ys, hv - 1)
    x1 = torch.minimum(xs + 1, wv - 1)
    x0 = torch.clamp(xs - 1, min=0)
    y1 = torch.minimum(ys + 1, hv - 1)
    y0 = torch.clamp(ys - 1, min=0)
    shape = (B, C, H, W)
    gx = (potentials.gather(3, x1.expand(shape)) - potentials.gather(3, x0.expand(shape))) \
        / (x1 - x0).to(potentials.dtype)
    gy = (potentials.gather(2, y1.expand(shape)) - potentials.gather(2, y0.expand(shape))) \
        / (y1 - y0).to(potentials.dtype)
    return -torch.stack([gx, gy], dim=2)


def _grid_sample(field, points, origin, sizes):
    """field [B, C, H, W], points [B, N, 2] -> values [B, N, C], inside [B, N]."""
    torch, _ = require_torch()
    H, W = field.shape[-2:]
    rel = points - origin[:, None, :]
    grid = torch.empty_like(rel)
    grid[..., 0] = rel[..., 0] * (2.0 / (W - 1)) - 1.0
    grid[..., 1] = rel[..., 1] * (2.0 / (H - 1)) - 1.0
    vals = torch.nn.functional.grid_sample(field, grid[:, :, None, :], mode="bilinear",
                                           padding_mode="zeros", align_corners=True)
    inside = ((rel[..., 0] >= 0) & (rel[..., 1] >= 0)
              & (rel[..., 0] <= sizes[:, None, 1] - 1) & (rel[..., 1] <= sizes[:, None, 0] - 1))
    return vals[..., 0].transpose(1, 2), inside


def sample_bilinear_batch(field, points, *, origin=None):
    """Bilinear samples of B fields at B sets of sub-pixel points (``grid_sample``).

    Parameters
    ----------
    field : Tensor [B, C, H, W]
        H, W >= 2.
    points : Tensor [B, N, 2]
        (x, y) image pixels: x right, y down, origin at the centre of the top-left pixel.
    origin : Tensor [B, 2] or [2], optional
        Image position of ``field[b, :, 0, 0]`` (a crop's corner); default (0, 0).

    Returns
    -------
    values : Tensor [B, N, C]
        NaN for points outside the field.

    Examples
    --------
    >>> import torch
    >>> f = torch.arange(12.0, dtype=torch.float64).reshape(1, 1, 3, 4)
    >>> sample_bilinear_batch(f, torch.tensor([[[1.5, 1.0], [0.0, 0.5]]],
    ...                                       dtype=torch.float64))[0, :, 0].tolist()
    [5.5, 2.0]
    """
    torch, _ = require_torch()
    _check_tensor(field, "field", 4, ("B", "C", "H", "W"))
    _check_tensor(points, "points", 3, ("B", "N", "2"))
    B, C, H, W = field.shape
    if points.shape[0] != B or points.shape[2] != 2:
        raise ValueError(f"points must have shape [B, N, 2] with B = {B} (field's batch), "
                         f"got {list(points.shape)}")
    if H < 2 or W < 2:
        raise ValueError(f"field must be at least 2x2 (H, W), got {list(field.shape)}")
    if points.dtype != field.dtype or points.device != field.device:
        raise ValueError(f"points ({points.dtype}, {points.device}) must match field "
                         f"({field.dtype}, {field.device})")
    if origin is None:
        org = torch.zeros(B, 2, dtype=field.dtype, device=field.device)
    else:
        org = torch.as_tensor(origin, dtype=field.dtype, device=field.device)
        if org.shape == (2,):
            org = org.expand(B, 2)
        if org.shape != (B, 2):
            raise ValueError(f"origin must have shape [B, 2] or [2], got {list(org.shape)}")
    sizes = torch.tensor([H, W], dtype=field.dtype, device=field.device).expand(B, 2)
    vals, inside = _grid_sample(field, points, org, sizes)
    return torch.where(inside[..., None], vals, torch.full_like(vals, float("nan")))


# --------------------------------------------------------------------- snakes

def _matrix_key(system: ContourSystem):
    """What the matrix of eq. 11 depends on (systems with equal keys share an inverse)."""
    parts = [system.starts, system.closed, system.b_n, system.kappa, system.gdt,
             system.nxt, system.a_s if system.split else np.zeros(0)]
    return (bool(system.split),) + tuple(np.ascontiguousarray(a).tobytes() for a in parts)


def _block_matrices(system: ContourSystem):
    """Dense diagonal blocks of ``gamma/dt I + K`` (as ContourSystem.matrix(), per contour)."""
    blocks = []
    gdt = float(system.gdt[0])
    for k in range(system.n_contours):
        s, e = int(system.starts[k]), int(system.starts[k + 1])
        n = e - s
        A = np.diag(gdt + system.kappa[s:e])
        closed = bool(system.closed[k])
        centres = np.arange(n) if closed else np.arange(1, n - 1)
        for j in centres:
            b = system.b_n[s + j]
            if b == 0:
                continue
            nb = [(j - 1) % n, j, (j + 1) % n]
            d = np.zeros(n)
            np.add.at(d, nb, [1.0, -2.0, 1.0])
            A += b * np.outer(d, d)
        if system.split:
            for i in range(n):
                j = int(system.nxt[s + i])
                if j >= 0:
                    d = np.zeros(n)
                    d[i] += 1.0
                    d[j - s] -= 1.0
                    A += system.a_s[s + i] * np.outer(d, d)
        blocks.append(A)
    return blocks


@dataclass
class BatchRelaxResult:
    """What :meth:`TorchContourSystem.relax` did, per batch element (NumPy arrays).

    Attributes
    ----------
    iterations : ndarray of int (B,)
    max_move, rms_move : ndarray of float (B,)
        Largest / root-mean-square node move in each element's last step.
    converged : ndarray of bool (B,)
    outside : ndarray of bool (B, K)
        Contours with a node that left its force field (force taken as 0).
    """

    iterations: np.ndarray
    max_move: np.ndarray
    converged: np.ndarray
    outside: np.ndarray
    rms_move: np.ndarray

    def element(self, b: int, n_contours: int | None = None) -> RelaxResult:
        """The :class:`~trackers.snake_types.RelaxResult` of batch element ``b``."""
        k = self.outside.shape[1] if n_contours is None else n_contours
        return RelaxResult(int(self.iterations[b]), float(self.max_move[b]),
                           bool(self.converged[b]), self.outside[b, :k].copy(),
                           float(self.rms_move[b]))


class TorchContourSystem:
    """B contour systems relaxed together on a torch device (eq. 11, as trackers.snakes).

    Parameters
    ----------
    systems : ContourSystem or sequence of ContourSystem
        The systems (their topology, parameters, current positions and rest lengths).
        They may differ in contours and node counts; they are padded to K contours of
        M nodes. All must share ``gamma/dt`` and ``dt`` only within themselves.
    batch : int, optional
        With a single system: repeat it ``batch`` times (many frames, one layout).
    device : str or torch.device
        'cpu' (default), 'cuda', 'cuda:1', ...
    dtype : torch.float32 or torch.float64, optional
        Default float64 on the CPU, float32 elsewhere. The inverse is always computed
        in float64.
    num_threads : int or None
        torch CPU threads while relaxing (restored afterwards). The default 1 keeps
        the many small operations of a step out of OpenMP regions, whose spinning
        worker threads made steps 10-50 times slower on a busy two-core machine;
        None leaves torch's setting. Ignored on other devices.

    Notes
    -----
    The state (positions, rest lengths, strengths, anchors) is copied from the systems
    at construction and by :meth:`load`; :meth:`store` copies positions and rest
    lengths back. The matrix depends only on the topology and on a, b, gamma, dt and
    the end anchors, which ``ContourSystem`` never changes after construction.

    Examples
    --------
    >>> import numpy as np, torch
    >>> from trackers.potentials import gaussian_potential
    >>> from trackers.sampling import force_field
    >>> from trackers.snakes import paper_equivalent_strength
    >>> yy, xx = np.mgrid[:64, :64]
    >>> img = ((xx - 32) ** 2 + (yy - 32) ** 2 < 15 ** 2).astype(float)
    >>> t = np.linspace(0, 2 * np.pi, 60, endpoint=False)
    >>> init = np.c_[32 + 18 * np.cos(t), 32 + 18 * np.sin(t)]
    >>> prm = SnakeParams(p=paper_equivalent_strength(2.0))
    >>> ref = ContourSystem([Contour(init, closed=True)], prm)
    >>> ts = TorchContourSystem(ref, batch=3)
    >>> F = torch.from_numpy(force_field(gaussian_potential(img, 2.0))).double()
    >>> res = ts.relax(forces=F.permute(2, 0, 1)[None, None].expand(3, 1, 2, 64, 64))
    >>> _ = ref.relax(force_field(gaussian_potential(img, 2.0)))
    >>> bool(np.abs(ts.positions(2) - ref.positions).max() < 1e-6), bool(res.converged.all())
    (True, True)
    """

    def __init__(self, systems, *, batch: int | None = None, device="cpu", dtype=None,
                 num_threads: int | None = 1):
        torch, _ = require_torch()
        self.device, self.dtype = _device_dtype(device, dtype)
        if num_threads is not None and int(num_threads) < 1:
            raise ValueError(f"num_threads must be >= 1 or None, got {num_threads}")
        self.num_threads = None if num_threads is None else int(num_threads)
        if isinstance(systems, ContourSystem):
            systems = [systems] * (1 if batch is None else int(batch))
        elif batch is not None:
            raise ValueError("batch repeats a single ContourSystem; give one system, or "
                             "a sequence without batch")
        systems = list(systems)
        if not systems or not all(isinstance(s, ContourSystem) for s in systems):
            raise ValueError("systems must be a ContourSystem or a non-empty sequence of them")
        if batch is not None and batch < 1:
            raise ValueError(f"batch must be >= 1, got {batch}")
        self.systems = systems
        B = len(systems)
        K = max(s.n_contours for s in systems)
        M = max(int(np.diff(s.starts).max()) for s in systems)
        self.B, self.K, self.M = B, K, M
        f64 = np.float64
        valid = np.zeros((B, K, M), bool)
        nxt = np.tile(np.arange(M), (B, K, 1))
        prv = nxt.copy()
        spring = np.zeros((B, K, M), bool)
        a_s = np.zeros((B, K, M), f64)
        nu_s = np.zeros((B, K, M), f64)
        kappa = np.zeros((B, K, M), f64)
        normal = np.zeros((B, K, M), bool)
        fidx = np.zeros((B, K), np.int64)
        self._flat = []  # per element: padded flat position (k * M + m) of each node
        unique: dict[int, int] = {}
        inv_index = np.zeros(B, np.int64)
        inverses = []
        gdt = np.zeros(B)
        dt = np.zeros(B)
        n_nodes = np.zeros(B, np.int64)
        for b, s in enumerate(systems):
            idx = np.empty(s.n_nodes, np.int64)
            for k in range(s.n_contours):
                st, en = int(s.starts[k]), int(s.starts[k + 1])
                n = en - st
                idx[st:en] = k * M + np.arange(n)
                valid[b, k, :n] = True
                nx = s.nxt[st:en]
                pv = s.prv[st:en]
                nxt[b, k, :n] = np.where(nx >= 0, nx - st, np.arange(n))
                prv[b, k, :n] = np.where(pv >= 0, pv - st, np.arange(n))
                spring[b, k, :n] = (nx >= 0) & (s.a_s[st:en] != 0.0)
                a_s[b, k, :n] = s.a_s[st:en]
                nu_s[b, k, :n] = s.nu_s[st:en]
                kappa[b, k, :n] = s.kappa[st:en]
                normal[b, k, :n] = s.normal_only[st:en]
                fidx[b, k] = int(s.fidx[st])
            self._flat.append(idx)
            gdt[b] = float(s.gdt[0])
            dt[b] = float(s.dts[0])
            n_nodes[b] = s.n_nodes
            key = _matrix_key(s)
            if key not in unique:
                blocks = _block_matrices(s)
                inv = np.zeros((K, M, M))
                for k, A in enumerate(blocks):
                    n = A.shape[0]
                    inv[k, :n, :n] = np.linalg.inv(A)
                unique[key] = len(inverses)
                inverses.append(inv)
            inv_index[b] = unique[key]
        self.n_factorizations = len(inverses)

        def T(a, dtype=None):
            return torch.as_tensor(a, device=self.device,
                                   dtype=self.dtype if dtype is None else dtype)

        inv = np.stack(inverses)
        # one inverse shared by the batch (broadcast) when all systems are the same
        self._Ainv = T(inv[0])[None] if len(inverses) == 1 else T(inv[inv_index])
        self._valid = T(valid, torch.bool)
        self._nxt = T(nxt, torch.long)
        self._prv = T(prv, torch.long)
        self._spring = T(spring, torch.bool)
        self._a = T(a_s)
        self._nu = T(nu_s)
        self._kappa = T(kappa)
        self._normal = T(normal, torch.bool)
        self._any_normal = bool(normal.any())
        self.fidx = fidx
        self._gdt = T(gdt)
        self._dt = T(dt)
        self._n_nodes = T(n_nodes)
        self.n_contours = np.array([s.n_contours for s in systems])
        self.split = np.array([s.split for s in systems])
        self.max_step = np.array([s.max_step for s in systems])
        if len(set(self.split.tolist())) > 1:
            raise ValueError("all systems of a batch must use the same tension scheme")
        self._split = bool(self.split[0])
        self._max_step = T(self.max_step)
        self.load()

    # ------------------------------------------------------------------ state
    def _pad(self, arrays, width):
        """Per-element flat (N_b, width) arrays -> padded (B, K, M, width) float64."""
        out = np.zeros((self.B, self.K * self.M, width))
        for b, a in enumerate(arrays):
            out[b, self._flat[b]] = np.asarray(a, np.float64).reshape(len(self._flat[b]), width)
        return out.reshape(self.B, self.K, self.M, width)

    def load(self, elements=None) -> None:
        """Copy positions, rest lengths, strengths and anchors from the NumPy systems.

        Parameters
        ----------
        elements : sequence of int, optional
            Only these batch elements (default all).
        """
        torch, _ = require_torch()
        st = self.systems
        X = self._pad([s.X for s in st], 2)
        rest = self._pad([s.rest for s in st], 1)[..., 0]
        p = self._pad([s.p_n for s in st], 1)[..., 0]
        anchor = self._pad([s.anchor for s in st], 2)
        new = {"X": X, "rest": rest, "p": p, "anchor": anchor}
        if elements is None or not hasattr(self, "X"):
            for name, v in new.items():
                setattr(self, name, torch.as_tensor(v, device=self.device, dtype=self.dtype))
            return
        sel = torch.as_tensor(np.asarray(elements, np.int64), device=self.device)
        for name, v in new.items():
            cur = getattr(self, name)
            cur[sel] = torch.as_tensor(v, device=self.device, dtype=self.dtype)[sel]

    def store(self, elements=None) -> None:
        """Copy positions and rest lengths back into the NumPy systems (in place)."""
        X = self.X.detach().cpu().numpy().astype(np.float64).reshape(self.B, -1, 2)
        rest = self.rest.detach().cpu().numpy().astype(np.float64).reshape(self.B, -1)
        for b in range(self.B) if elements is None else elements:
            s = self.systems[b]
            s.X[:] = X[b, self._flat[b]]
            s.rest[:] = rest[b, self._flat[b]]

    def positions(self, b: int) -> np.ndarray:
        """Node positions (N_b, 2) of batch element ``b``, in the NumPy system's order."""
        if not 0 <= int(b) < self.B:
            raise ValueError(f"batch element {b} out of range 0..{self.B - 1}")
        X = self.X[int(b)].detach().cpu().numpy().astype(np.float64).reshape(-1, 2)
        return X[self._flat[int(b)]]

    def rest_lengths(self, b: int) -> np.ndarray:
        """Current rest lengths (N_b,) of batch element ``b``."""
        r = self.rest[int(b)].detach().cpu().numpy().astype(np.float64).reshape(-1)
        return r[self._flat[int(b)]]

    # ------------------------------------------------------------------ fields
    def _origins(self, origin, B, Kf):
        torch, _ = require_torch()
        org = torch.as_tensor(np.asarray(origin, np.float64) if not isinstance(
            origin, torch.Tensor) else origin, device=self.device, dtype=self.dtype)
        if org.shape in ((2,), (Kf, 2)):
            org = org.expand(B, Kf, 2)
        if org.shape != (B, Kf, 2) or not torch.isfinite(org).all():
            raise ValueError(f"origin must be (x, y), [Kf, 2] or [B, Kf, 2] with Kf = {Kf}, "
                             f"got {list(org.shape)}")
        return org

    def _sizes(self, sizes, B, Kf, H, W):
        torch, _ = require_torch()
        if sizes is None:
            return torch.tensor([H, W], device=self.device, dtype=torch.long).expand(B, Kf, 2)
        sz = torch.as_tensor(np.asarray(sizes) if not isinstance(sizes, torch.Tensor)
                             else sizes, device=self.device).long()
        if sz.shape != (B, Kf, 2):
            raise ValueError(f"sizes must have shape [B, Kf, 2] = [{B}, {Kf}, 2], got "
                             f"{list(sz.shape)}")
        if (sz < 2).any() or (sz[..., 0] > H).any() or (sz[..., 1] > W).any():
            raise ValueError(f"sizes must lie in [2, {H}] x [2, {W}]")
        return sz

    def _per_contour(self, *arrays):
        """[B, Kf, ...] per field -> [B, K, ...] per contour (Contour.field)."""
        torch, _ = require_torch()
        Kf = arrays[0].shape[1]
        if Kf == self.K and (self.fidx == np.arange(self.K)).all():
            return arrays
        bi = torch.arange(self.B, device=self.device)[:, None]
        fi = torch.as_tensor(self.fidx, device=self.device)
        return tuple(a[bi, fi] for a in arrays)

    def _prepare_fields(self, forces, potentials, origin, sizes):
        """A sampler X [B, K, M, 2] -> (force [B, K, M, 2], inside [B, K, M])."""
        torch, _ = require_torch()
        B, K, M = self.B, self.K, self.M
        if (forces is None) == (potentials is None):
            raise ValueError("give exactly one of forces or potentials")
        need = int(self.fidx.max()) + 1
        if forces is not None:
            _check_tensor(forces, "forces", 5, ("B", "Kf", "2", "H", "W"))
            if forces.shape[0] != B or forces.shape[2] != 2:
                raise ValueError(f"forces must have shape [B, Kf, 2, H, W] with B = {B}, got "
                                 f"{list(forces.shape)}")
            _, Kf, _, H, W = forces.shape
            if H < 2 or W < 2:
                raise ValueError(f"fields must be at least 2x2 (H, W), got {H}x{W}")
            if need > Kf:
                raise ValueError(f"a contour uses field {need - 1} but only {Kf} were given")
            F = forces.to(self.device, self.dtype)
            if not torch.isfinite(F).all():
                raise ValueError("forces contain NaN or infinite values")
            org, sz = self._per_contour(self._origins(origin, B, Kf),
                                        self._sizes(sizes, B, Kf, H, W).to(self.dtype))
            Fk = self._per_contour(F)[0].reshape(B * K, 2, H, W)
            org, sz = org.reshape(B * K, 2), sz.reshape(B * K, 2)

            def sample(X):
                vals, inside = _grid_sample(Fk, X.reshape(B * K, M, 2), org, sz)
                return vals.reshape(B, K, M, 2), inside.reshape(B, K, M)

            return sample, org.reshape(B, K, 2), sz.reshape(B, K, 2)
        # potentials: one flat buffer, -grad P from the 4x4 pixels around each node
        if isinstance(potentials, torch.Tensor):
            _check_tensor(potentials, "potentials", 4, ("B", "Kf", "H", "W"))
            if potentials.shape[0] != B:
                raise ValueError(f"potentials must have shape [B, Kf, H, W] with B = {B}, got "
                                 f"{list(potentials.shape)}")
            _, Kf, H, W = potentials.shape
            if H < 2 or W < 2:
                raise ValueError(f"fields must be at least 2x2 (H, W), got {H}x{W}")
            buf = potentials.to(self.device, self.dtype).contiguous().reshape(-1)
            sz = self._sizes(sizes, B, Kf, H, W)
            offset = torch.arange(B * Kf, device=self.device).reshape(B, Kf) * (H * W)
            stride = torch.full((B, Kf), W, device=self.device, dtype=torch.long)
        else:
            plists = list(potentials)
            if len(plists) != B:
                raise ValueError(f"potentials must be a [B, Kf, H, W] tensor or B = {B} "
                                 f"sequences of 2-D fields, got {len(plists)}")
            plists = [[q if isinstance(q, torch.Tensor) else torch.from_numpy(
                np.ascontiguousarray(q)) for q in pl] for pl in plists]
            Kf = max(len(pl) for pl in plists)
            shapes = np.full((B, Kf, 2), 2, np.int64)
            offs = np.zeros((B, Kf), np.int64)
            parts, pos = [], 0
            for b, pl in enumerate(plists):
                for f, q in enumerate(pl):
                    if q.ndim != 2 or q.shape[0] < 2 or q.shape[1] < 2:
                        raise ValueError(f"batch element {b}: field {f} must be 2-D and at "
                                         f"least 2x2, got shape {tuple(q.shape)}")
                    shapes[b, f] = q.shape
                    offs[b, f] = pos
                    pos += q.numel()
                    parts.append(q.reshape(-1).to(torch.float64))
                for f in range(len(pl), Kf):  # missing fields: a 2x2 zero field
                    offs[b, f] = pos
                    pos += 4
                    parts.append(torch.zeros(4, dtype=torch.float64))
            if sizes is not None:
                raise ValueError("sizes go with a padded potentials tensor, not with a "
                                 "sequence of fields")
            buf = torch.cat(parts).to(self.device, self.dtype)
            sz = torch.as_tensor(shapes, device=self.device)
            offset = torch.as_tensor(offs, device=self.device)
            stride = sz[..., 1].clone()
        if need > Kf:
            raise ValueError(f"a contour uses field {need - 1} but only {Kf} were given")
        if not torch.isfinite(buf).all():
            raise ValueError("potentials contain NaN or infinite values")
        org = self._origins(origin, B, Kf)
        org, sz, offset, stride = self._per_contour(org, sz, offset, stride)
        hk, wk = sz[..., 0, None], sz[..., 1, None]
        offset, stride = offset[..., None], stride[..., None]
        org_ = org[:, :, None, :]
        span = torch.arange(-1, 3, device=self.device)

        def sample(X):
            rel = X - org_
            xf, yf = rel[..., 0], rel[..., 1]
            inside = (xf >= 0) & (yf >= 0) & (xf <= wk - 1) & (yf <= hk - 1)
            xc = torch.minimum(torch.clamp(xf, min=0.0), (wk - 1).to(xf.dtype))
            yc = torch.minimum(torch.clamp(yf, min=0.0), (hk - 1).to(yf.dtype))
            x0 = torch.minimum(xc.floor().long(), wk - 2)
            y0 = torch.minimum(yc.floor().long(), hk - 2)
            tx, ty = xc - x0, yc - y0
            cols = torch.minimum(torch.clamp(x0[..., None] + span, min=0), wk[..., None] - 1)
            rows = torch.minimum(torch.clamp(y0[..., None] + span, min=0), hk[..., None] - 1)
            v = buf[offset[..., None, None] + rows[..., :, None] * stride[..., None, None]
                    + cols[..., None, :]]  # [B, K, M, 4 rows, 4 cols]
            dc = (cols[..., 2:] - cols[..., :2]).to(v.dtype)  # [B, K, M, 2]
            dr = (rows[..., 2:] - rows[..., :2]).to(v.dtype)
            gx = (v[..., 1:3, 2:] - v[..., 1:3, :2]) / dc[..., None, :]  # rows y0, y0+1
            gy = (v[..., 2:, 1:3] - v[..., :2, 1:3]) / dr[..., :, None]
            wx = torch.stack([1.0 - tx, tx], -1)
            wy = torch.stack([1.0 - ty, ty], -1)
            w = wy[..., :, None] * wx[..., None, :]
            f = -torch.stack([(w * gx).sum((-2, -1)), (w * gy).sum((-2, -1))], -1)
            return f, inside

        return sample, org, sz.to(self.dtype)

    # ------------------------------------------------------------------ dynamics
    def relax(self, forces=None, *, potentials=None, origin=(0.0, 0.0), sizes=None,
              user_forces=None, tol=1e-3, max_iter=1000, min_iter=1, criterion="max",
              active=None, check_every: int | None = None) -> BatchRelaxResult:
        """Integrate eq. 11 until each element's nodes move less than ``tol`` in a step.

        Parameters
        ----------
        forces : Tensor [B, Kf, 2, H, W], optional
            Force fields ``-grad P`` (strength 1); contour k of element b uses field
            ``Contour.field``.
        potentials : Tensor [B, Kf, H, W] or B sequences of 2-D arrays, optional
            Instead of ``forces``: the potentials. ``-grad P`` is taken at the four
            pixels around each node (central differences, one-sided on each field's
            border) and interpolated bilinearly, exactly as
            ``ContourSystem.relax(potentials=...)``; no force field is built. A
            sequence (element b: its Kf fields, of any sizes, e.g. the per-contour
            boxes of a tracker) is packed into one flat buffer without padding.
        origin : (x, y), [Kf, 2] or [B, Kf, 2]
            Image position of each field's pixel [0, 0].
        sizes : [B, Kf, 2] of int (h, w), optional
            With a tensor of fields: the valid size of each (smaller fields
            zero-padded to H x W).
        user_forces : array_like or Tensor [B, K, M, 2], optional
            Extra constant forces (padded layout, see :meth:`pad`).
        tol : float or array_like (B,)
        max_iter, min_iter : int or array_like (B,)
        criterion : {'max', 'rms'} or sequence of them, one per element
        active : array_like of bool (B,), optional
            Elements to relax (the others are left untouched; default all).
        check_every : int, optional
            Steps between host synchronisations to test whether every element is done
            (frozen elements do not change, so the result does not depend on it).
            Default 1 on the CPU, 8 elsewhere.

        Returns
        -------
        BatchRelaxResult

        Raises
        ------
        ValueError
            For bad fields or parameters, or when a node starts outside its field.
        """
        torch, _ = require_torch()
        if self.device.type != "cpu" or self.num_threads is None:
            return self._relax(forces, potentials, origin, sizes, user_forces, tol, max_iter,
                               min_iter, criterion, active, check_every)
        before = torch.get_num_threads()
        torch.set_num_threads(self.num_threads)
        try:
            return self._relax(forces, potentials, origin, sizes, user_forces, tol, max_iter,
                               min_iter, criterion, active, check_every)
        finally:
            torch.set_num_threads(before)

    def _relax(self, forces, potentials, origin, sizes, user_forces, tol, max_iter, min_iter,
               criterion, active, check_every):
        torch, _ = require_torch()
        B, K, M = self.B, self.K, self.M
        sample, org, sz = self._prepare_fields(forces, potentials, origin, sizes)
        dev, dt_ = self.device, self.dtype

        def per_elem(v, name, kind=float):
            a = np.asarray(v, dtype=np.float64 if kind is float else np.int64)
            if a.ndim == 0:
                a = np.full(B, a)
            if a.shape != (B,):
                raise ValueError(f"{name} must be a scalar or have {B} entries, got shape "
                                 f"{a.shape}")
            return a

        tol_a = per_elem(tol, "tol")
        if not np.isfinite(tol_a).all() or (tol_a < 0).any():
            raise ValueError(f"tol must be >= 0, got {tol}")
        max_a = per_elem(max_iter, "max_iter", int)
        min_a = per_elem(min_iter, "min_iter", int)
        if (max_a < 1).any() or (min_a < 0).any():
            raise ValueError("max_iter must be >= 1 and min_iter >= 0")
        crit = [criterion] * B if isinstance(criterion, str) else list(criterion)
        if len(crit) != B or any(c not in ("max", "rms", "each") for c in crit):
            raise ValueError(f"criterion must be 'max', 'rms' or 'each' (or one per "
                             f"element), got {criterion!r}")
        act = np.ones(B, bool) if active is None else np.asarray(active, bool)
        if act.shape != (B,):
            raise ValueError(f"active must have {B} entries, got shape {act.shape}")
        if check_every is None:
            check_every = 1 if dev.type == "cpu" else 8
        check_every = max(int(check_every), 1)
        if user_forces is None:
            user = torch.zeros(B, K, M, 2, device=dev, dtype=dt_)
        else:
            user = torch.as_tensor(user_forces, device=dev, dtype=dt_)
            if user.shape != (B, K, M, 2) or not torch.isfinite(user).all():
                raise ValueError(f"user_forces must be a finite [B, K, M, 2] = [{B}, {K}, {M},"
                                 f" 2] tensor, got {list(user.shape)}")
        # nodes must start inside their field
        rel = self.X - org[:, :, None, :]
        bad = ((rel[..., 0] < 0) | (rel[..., 1] < 0) | (rel[..., 0] > sz[..., 1, None] - 1)
               | (rel[..., 1] > sz[..., 0, None] - 1)) & self._valid
        bad = bad & torch.as_tensor(act, device=dev)[:, None, None]
        if bad.any():
            b, k, m = (int(v) for v in torch.nonzero(bad)[0])
            s = self.systems[b]
            x, y = (float(v) for v in self.X[b, k, m])
            raise ValueError(f"batch element {b}: node {m} of contour {s.names[k]!r} at "
                             f"(x={x:.2f}, y={y:.2f}) lies outside its field")
        tol_t = torch.as_tensor(tol_a, device=dev, dtype=dt_)
        max_t = torch.as_tensor(max_a, device=dev)
        min_t = torch.as_tensor(min_a, device=dev)
        rms_t = torch.as_tensor([c == "rms" for c in crit], device=dev)
        each_t = torch.as_tensor([c == "each" for c in crit], device=dev)
        any_each = "each" in crit
        running = torch.as_tensor(act, device=dev)
        # per contour, for 'each': a contour stops on its own first step below tol
        moving = running[:, None].expand(B, K).clone()
        it = torch.zeros(B, dtype=torch.long, device=dev)
        move = torch.full((B,), float("inf"), device=dev, dtype=dt_)
        rms = torch.full((B,), float("nan"), device=dev, dtype=dt_)
        outside = torch.zeros(B, K, dtype=torch.bool, device=dev)
        valid = self._valid
        vmask = valid.to(dt_)
        gdt = self._gdt[:, None, None, None]
        dtv = self._dt[:, None, None]
        ms = self._max_step[:, None, None]
        nxt2 = self._nxt[..., None].expand(B, K, M, 2)
        prv2 = self._prv[..., None].expand(B, K, M, 2)
        kap_anchor = self._kappa[..., None] * self.anchor + user
        p = self.p[..., None]
        X, rest = self.X, self.rest
        step = 0
        n_max = int(max_a[act].max()) if act.any() else 0
        while step < n_max:
            # forces: bilinear samples of the fields; 0 (and 'outside') off the field
            vals, inside = sample(X)
            Fx = torch.where(inside[..., None], vals, 0.0)
            outside |= ((~inside) & valid).any(-1) & running[:, None]
            if self._any_normal:
                t = X.gather(2, nxt2) - X.gather(2, prv2)
                tl = (t * t).sum(-1, keepdim=True)
                proj = (Fx * t).sum(-1, keepdim=True) / torch.where(tl > 1e-18, tl, 1.0)
                Fx = torch.where(self._normal[..., None] & (tl > 1e-18), Fx - proj * t, Fx)
            R = gdt * X + p * Fx + kap_anchor
            # explicit tension (eq. 7) and viscoelastic rest lengths (eq. 8)
            r = X.gather(2, nxt2) - X
            L = torch.sqrt((r * r).sum(-1))
            e = L - rest
            num = -rest if self._split else e
            s = torch.where(self._spring & (L > 1e-12), self._a * num / torch.where(
                L > 1e-12, L, 1.0), 0.0)
            sr = s[..., None] * r
            R = R + sr
            R = R.scatter_add(2, nxt2, -sr)
            rest_new = torch.where(self._spring, torch.clamp(rest + dtv * self._nu * e,
                                                             min=0.0), rest)
            Xn = torch.matmul(self._Ainv, R)
            d = Xn - X
            d2 = (d * d).sum(-1)
            cap = (ms > 0) & (d2 > ms * ms)
            f = torch.where(cap, ms / torch.sqrt(torch.where(cap, d2, 1.0)), 1.0)
            Xn = torch.where(cap[..., None], X + f[..., None] * d, Xn)
            d2 = torch.where(cap, ms * ms, d2) * vmask
            run3 = running[:, None, None]
            if any_each:
                d2 = d2 * moving[..., None]
                run3 = run3 & moving[..., None]
            mv = torch.sqrt(d2.amax(dim=(1, 2)))
            rm = torch.sqrt(d2.sum(dim=(1, 2)) / self._n_nodes)
            X = torch.where(run3[..., None], Xn, X)
            rest = torch.where(running[:, None, None], rest_new, rest)
            move = torch.where(running, mv, move)
            rms = torch.where(running, rm, rms)
            it = it + running.long()
            stat = torch.where(rms_t, rms, move)
            done = (it >= min_t) & (stat < tol_t)
            if any_each:
                settled = (it >= min_t)[:, None] & (d2.amax(dim=2) < (tol_t * tol_t)[:, None])
                moving = moving & ~(settled & each_t[:, None] & running[:, None])
                done = torch.where(each_t, ~moving.any(1), done)
            done = done | ~torch.isfinite(move) | (it >= max_t)
            running = running & ~done
            step += 1
            if step % check_every == 0 and not bool(running.any()):
                break
        self.X, self.rest = X, rest
        if not bool(torch.isfinite(X).all()):
            raise FloatingPointError("contour positions became non-finite; the parameters "
                                     "are unstable for this potential (lower p or a)")
        stat = torch.where(rms_t, rms, move)
        conv = torch.where(each_t, ~moving.any(1), stat < tol_t).cpu().numpy() & act
        return BatchRelaxResult(it.cpu().numpy(), move.cpu().numpy().astype(float),
                                conv, outside.cpu().numpy(), rms.cpu().numpy().astype(float))

    def step(self, forces=None, n: int = 1, **kwargs) -> BatchRelaxResult:
        """Take exactly ``n`` time steps in every element. See :meth:`relax`."""
        return self.relax(forces, tol=0.0, max_iter=n, min_iter=n, **kwargs)

    def pad(self, values) -> np.ndarray:
        """Per-element flat node arrays [(N_b, 2)] -> the padded layout (B, K, M, 2)."""
        if len(values) != self.B:
            raise ValueError(f"need one array per batch element ({self.B}), got {len(values)}")
        for b, v in enumerate(values):
            if np.shape(v) != (len(self._flat[b]), 2):
                raise ValueError(f"batch element {b}: expected shape ({len(self._flat[b])}, 2),"
                                 f" got {np.shape(v)}")
        return self._pad(values, 2)

    def solve(self, rhs):
        """Apply ``A^{-1}`` to a padded right-hand side [B, K, M, 2] (for tests)."""
        torch, _ = require_torch()
        R = torch.as_tensor(rhs, device=self.device, dtype=self.dtype)
        return torch.matmul(self._Ainv, R)


def snake_relax_batch(points, forces, *, closed: bool = False, params: SnakeParams | None = None,
                      origin=None, normal_forces: bool = False, max_step: float | None = None,
                      tension: str = "explicit", n_steps: int | None = None, tol: float = 1e-3,
                      max_iter: int = 1000, criterion: str = "max", factor=None):
    """Relax one contour per batch element in its own force field (eq. 11).

    Parameters
    ----------
    points : Tensor [B, N, 2]
        Initial nodes (x, y) of each element's contour; rest lengths are the initial
        separations, as :class:`~trackers.snake_types.Contour`.
    forces : Tensor [B, 2, H, W]
        ``-grad P`` (strength 1) for each element.
    closed, normal_forces : bool
        As :class:`~trackers.snake_types.Contour`.
    params : SnakeParams, optional
    origin : Tensor [B, 2], optional
        Image position of each field's pixel [0, 0].
    max_step : float, optional
        Per-step move cap in pixels.
    tension : {'explicit', 'split'}
    n_steps : int, optional
        Take exactly this many steps (no equilibrium test).
    tol, max_iter, criterion
        Equilibrium test otherwise (see :meth:`TorchContourSystem.relax`).
    factor : TorchContourSystem, optional
        A system built by an earlier call for the same N, closed, params, tension and
        max_step (its inverse is reused: no new factorisation).

    Returns
    -------
    points : Tensor [B, N, 2]
    result : BatchRelaxResult
    system : TorchContourSystem
        Pass it back as ``factor`` to skip the set-up next time.

    Examples
    --------
    >>> import torch
    >>> x = torch.linspace(5, 25, 11, dtype=torch.float64)
    >>> pts = torch.stack([x, torch.full_like(x, 12.0)], -1)[None].repeat(2, 1, 1)
    >>> yy = torch.arange(30.0, dtype=torch.float64)[:, None].expand(30, 30)
    >>> P = -torch.exp(-0.5 * ((yy - 15.0) / 2) ** 2)[None, None] * 50  # ravine at y=15
    >>> out, res, _ = snake_relax_batch(pts, force_field_batch(P.repeat(2, 1, 1, 1))[:, 0],
    ...                                 params=SnakeParams(p=0.1))
    >>> round(float(out[:, :, 1].mean()), 2)
    15.0
    """
    torch, _ = require_torch()
    _check_tensor(points, "points", 3, ("B", "N", "2"))
    _check_tensor(forces, "forces", 4, ("B", "2", "H", "W"))
    B, N, two = points.shape
    if two != 2:
        raise ValueError(f"points must have shape [B, N, 2], got {list(points.shape)}")
    if forces.shape[0] != B or forces.shape[1] != 2:
        raise ValueError(f"forces must have shape [B, 2, H, W] with B = {B}, got "
                         f"{list(forces.shape)}")
    pts = points.detach().cpu().numpy().astype(np.float64)
    if factor is None:
        base = ContourSystem([Contour(pts[0], closed=closed, normal_forces=normal_forces)],
                             params, tension=tension, max_step=max_step)
        systems = [base] + [ContourSystem.__new__(ContourSystem) for _ in range(B - 1)]
        for b in range(1, B):  # same topology and matrix, own positions / rest lengths
            s = systems[b]
            s.__dict__.update(base.__dict__)
            s.X = pts[b].copy()
            s.rest = ContourSystem._initial_rest(Contour(pts[b], closed=closed), pts[b], "c")
            s.anchor = base.anchor.copy()
            s.p_n = base.p_n.copy()
        factor = TorchContourSystem(systems, device=points.device, dtype=points.dtype)
    else:
        if not isinstance(factor, TorchContourSystem) or factor.B != B or factor.M != N \
                or factor.K != 1:
            raise ValueError(f"factor must be a TorchContourSystem of {B} single contours of "
                             f"{N} nodes from an earlier call")
        factor.X = points.to(factor.device, factor.dtype).reshape(B, 1, N, 2).clone()
        r = torch.roll(factor.X, -1, dims=2) - factor.X
        rest = torch.sqrt((r * r).sum(-1))
        if not closed:
            rest[..., -1] = 0.0
        factor.rest = rest
    if origin is None:
        org = (0.0, 0.0)
    else:
        org = torch.as_tensor(origin, device=factor.device, dtype=factor.dtype)
        if org.shape != (B, 2):
            raise ValueError(f"origin must have shape [B, 2], got {list(org.shape)}")
        org = org[:, None, :]
    F = forces[:, None]
    if n_steps is not None:
        res = factor.step(F, int(n_steps), origin=org)
    else:
        res = factor.relax(F, origin=org, tol=tol, max_iter=max_iter, criterion=criterion)
    return factor.X[:, 0].clone(), res, factor


# --------------------------------------------------------------------- trackers

def check_backend(backend: str = "numpy", device=None) -> None:
    """Validate a backend / device choice up front (before any video is read).

    Parameters
    ----------
    backend : {'numpy', 'torch'}
    device : str, optional
        'cpu', 'cuda', 'cuda:N' (torch only; None = 'cpu').

    Raises
    ------
    ValueError
        Unknown backend, a device with the numpy backend, an unknown device or a
        CUDA device this torch build cannot reach.
    ImportError
        ``backend='torch'`` without the ``[torch]`` extra.

    Examples
    --------
    >>> check_backend("numpy")
    >>> check_backend("numpy", "cuda")
    Traceback (most recent call last):
    ...
    ValueError: device 'cuda' needs backend='torch' (the numpy backend runs on the CPU)
    """
    if backend not in BACKENDS:
        raise ValueError(f"backend must be one of {BACKENDS}, got {backend!r}")
    if backend == "numpy":
        if device not in (None, "cpu"):
            raise ValueError(f"device {device!r} needs backend='torch' (the numpy backend "
                             "runs on the CPU)")
        return
    _device_dtype(device, None)


def make_tracker(layout, *, backend: str = "numpy", device=None, dtype=None,
                 num_threads: int | None = 1, **kwargs):
    """A :class:`~trackers.tracking.Tracker` on the chosen backend.

    Parameters
    ----------
    layout : FaceLayout
    backend : {'numpy', 'torch'}
        'numpy': the Numba kernels. 'torch': the same tracker (same potentials,
        quality, end relocation and re-initialisation) whose relaxations run on
        :class:`TorchContourSystem`.
    device : str, optional
        Torch device ('cpu', 'cuda', 'cuda:1'); only with ``backend='torch'``.
    dtype : torch dtype, optional
        Default float64 on the CPU, float32 elsewhere.
    num_threads : int or None
        torch CPU threads while relaxing (see :class:`TorchContourSystem`).
    **kwargs
        Passed to :class:`~trackers.tracking.Tracker` (``channel_order``, ``tol``...).

    Returns
    -------
    Tracker

    Examples
    --------
    >>> from trackers.layout import layout_from_eyes
    >>> lay = layout_from_eyes((96, 105), (159, 105), (256, 256))
    >>> type(make_tracker(lay, backend="numpy")).__name__
    'Tracker'
    """
    from trackers.tracking import Tracker

    check_backend(backend, device)
    if backend == "numpy":
        return Tracker(layout, **kwargs)
    tracker = Tracker(layout, **kwargs)
    ts = TorchContourSystem(tracker.system, device=device, dtype=dtype,
                            num_threads=num_threads)
    tracker.system.relax = _SingleRelay(ts)
    return tracker


def _as_field_list(potentials):
    if isinstance(potentials, np.ndarray) and potentials.ndim in (2, 3):
        return [potentials] if potentials.ndim == 2 else list(potentials)
    return [np.asarray(q) for q in potentials]


def _batched_relax(ts, requests):
    """Run ContourSystem.relax-style requests {b: kwargs} as one batched relaxation."""
    B = ts.B
    elems = sorted(requests)
    for kw in requests.values():
        if kw.get("forces") is not None or kw.get("user_forces") is not None:
            raise ValueError("the torch tracker relays potentials only (no forces / user "
                             "forces)")
    plists = [(_as_field_list(requests[b]["potentials"]) if b in requests else [])
              for b in range(B)]
    Kf = max(len(p) for p in plists)
    org = np.zeros((B, Kf, 2))
    for b in elems:
        o = np.asarray(requests[b].get("origin", (0.0, 0.0)), np.float64)
        org[b, :len(o) if o.ndim == 2 else Kf] = o
    tol = np.ones(B)
    max_iter = np.ones(B, np.int64)
    min_iter = np.ones(B, np.int64)
    crit = ["max"] * B
    for b in elems:
        kw = requests[b]
        tol[b] = kw.get("tol", 1e-3)
        max_iter[b] = kw.get("max_iter", 1000)
        min_iter[b] = kw.get("min_iter", 1)
        crit[b] = kw.get("criterion", "max")
    active = np.zeros(B, bool)
    active[elems] = True
    ts.load(elems)
    res = ts.relax(potentials=plists, origin=org, tol=tol,
                   max_iter=max_iter, min_iter=min_iter, criterion=crit, active=active)
    ts.store(elems)
    return {b: res.element(b, int(ts.n_contours[b])) for b in elems}


class _SingleRelay:
    """Stands in for ``ContourSystem.relax`` of one tracker (batch of one)."""

    def __init__(self, ts):
        self.ts = ts

    def __call__(self, forces=None, *, potentials=None, **kwargs):
        if forces is not None:
            raise ValueError("the torch tracker relays potentials only")
        kwargs["potentials"] = potentials
        return _batched_relax(self.ts, {0: kwargs})[0]


class _Batcher:
    """Collects relax calls from B tracker threads and runs them as one batch."""

    def __init__(self, ts):
        self.ts = ts
        self.cond = threading.Condition()
        self.running = 0
        self.pending: dict[int, dict] = {}
        self.results: dict[int, object] = {}

    def relay(self, b):
        def relax(forces=None, *, potentials=None, **kwargs):
            if forces is not None:
                raise ValueError("the torch tracker relays potentials only")
            kwargs["potentials"] = potentials
            with self.cond:
                self.pending[b] = kwargs
                self._maybe_run()
                while b not in self.results:
                    self.cond.wait()
                out = self.results.pop(b)
            if isinstance(out, BaseException):
                raise out
            return out
        return relax

    def _maybe_run(self):
        # called with the lock held: every running thread is waiting -> run the batch
        if self.pending and len(self.pending) == self.running:
            reqs, self.pending = self.pending, {}
            try:
                out = _batched_relax(self.ts, reqs)
            except Exception as exc:  # handed to every waiting thread
                out = dict.fromkeys(reqs, exc)
            self.results.update(out)
            self.cond.notify_all()

    def finished(self):
        with self.cond:
            self.running -= 1
            self._maybe_run()


class TorchTracker:
    """Track B videos at once: B trackers whose relaxations form one torch batch.

    Also the way to relax one layout on B independent frames at once (stills, or
    frames of one video tracked independently): ``TorchTracker([layout] * B)``.

    Each video has its own :class:`~trackers.tracking.Tracker` (its own layout,
    strengths, quality references, end relocation, re-initialisation); at every
    relaxation the trackers wait for one another and one
    :meth:`TorchContourSystem.relax` runs all of them (each stopping at its own
    equilibrium). Results equal B separate trackers on the torch backend.

    Parameters
    ----------
    layouts : sequence of FaceLayout
        One per video (node counts may differ).
    device, dtype, num_threads
        See :class:`TorchContourSystem`.
    **kwargs
        Passed to every :class:`~trackers.tracking.Tracker`.

    Examples
    --------
    >>> import numpy as np, cv2
    >>> from trackers.layout import layout_from_eyes
    >>> img = np.full((256, 256), 200, np.uint8)
    >>> lay = layout_from_eyes((96, 105), (159, 105), (256, 256))
    >>> for c in lay.contours.values():
    ...     _ = cv2.polylines(img, [np.round(c.points).astype(np.int32)], c.closed, 60, 3)
    >>> tt = TorchTracker([lay, lay])
    >>> [r.success for r in tt.track([img, img])]
    [True, True]
    """

    def __init__(self, layouts: Sequence, *, device=None, dtype=None,
                 num_threads: int | None = 1, **kwargs):
        from trackers.tracking import Tracker

        layouts = list(layouts)
        if not layouts:
            raise ValueError("layouts must hold at least one FaceLayout")
        self.trackers = [Tracker(lay, **kwargs) for lay in layouts]
        self.system = TorchContourSystem([t.system for t in self.trackers], device=device,
                                         dtype=dtype, num_threads=num_threads)
        self._batcher = _Batcher(self.system)
        for b, t in enumerate(self.trackers):
            t.system.relax = self._batcher.relay(b)

    @property
    def batch_size(self) -> int:
        return len(self.trackers)

    def track(self, frames, *, errors: str = "raise"):
        """Track one frame of every video.

        Parameters
        ----------
        frames : sequence of B frames (or None for a video to skip this time)
        errors : {'raise', 'return'}
            On a bad frame: raise the first error (naming the video), or put the
            exception in that video's slot of the returned list.

        Returns
        -------
        list of TrackResult (or None for skipped videos, exceptions with 'return')
        """
        if errors not in ("raise", "return"):
            raise ValueError(f"errors must be 'raise' or 'return', got {errors!r}")
        frames = list(frames)
        if len(frames) != self.batch_size:
            raise ValueError(f"need one frame per video ({self.batch_size}), got {len(frames)}")
        out: list = [None] * self.batch_size
        todo = [b for b, f in enumerate(frames) if f is not None]
        bat = self._batcher
        with bat.cond:
            bat.running = len(todo)

        def work(b):
            try:
                out[b] = self.trackers[b].track(frames[b])
            except Exception as exc:  # reported after every video is done
                out[b] = exc
            finally:
                bat.finished()

        threads = [threading.Thread(target=work, args=(b,), daemon=True) for b in todo]
        for th in threads:
            th.start()
        for th in threads:
            th.join()
        if errors == "raise":
            for b, r in enumerate(out):
                if isinstance(r, ValueError):
                    raise ValueError(f"video {b}: {r}") from r
                if isinstance(r, Exception):
                    raise r
        return out

    def run(self, videos):
        """Generator of per-frame result lists for B iterables of frames (zipped; a video
        that ends early gets None)."""
        iters = [iter(v) for v in videos]
        if len(iters) != self.batch_size:
            raise ValueError(f"need {self.batch_size} videos, got {len(iters)}")
        while True:
            frames = [next(i, None) for i in iters]
            if all(f is None for f in frames):
                return
            yield self.track(frames)
