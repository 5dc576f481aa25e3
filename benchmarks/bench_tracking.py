"""Tracking: frames per second of the nine-contour face layout on 640x480 video (decode excluded).

Single-threaded (``cv2.setNumThreads(1)``; the Numba kernels are serial). Per frame
the tracker computes the image potentials (edge + two valley widths, inside
the region the contours occupy), relaxes the nine contours from the previous
equilibrium to a movement threshold, relocates the feature ends, checks each
contour's quality, and computes the head frame and the 11 fiducials: everything
:meth:`trackers.Tracker.track` does. Frames are decoded (or drawn) beforehand.

Cases:

* ``synthetic 640x480``: a face drawn with OpenCV from the layout template (hair,
  brows, furrows, nostrils, eyes with irises, lips, mouth line, chin boss) on
  textured skin with sensor noise, moving: head translation and roll, brows
  raising, mouth opening, and (as in the face model) the hairline rising with the
  brows and the nostrils dropping as the mouth opens. Also reports the mean
  fiducial error against the drawn truth and the head frame's error against the
  rigid motion (the first frame's tracked frame moved by the true similarity):
  origin in px, scale in per cent, roll in radians (maxima over the frames).
* ``real <name>``: the first frames of each video in ``../shared/data/real`` when
  present (layout detected on the first frame), resized to 640x480.
"""

from __future__ import annotations

import statistics
import sys
import time
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from _harness import Figure, read_frames  # noqa: E402

from trackers import FIDUCIAL_NAMES, Tracker, detect_layout, layout_from_eyes  # noqa: E402
from trackers.layout import TEMPLATE  # noqa: E402

REAL = Path(__file__).resolve().parent.parent.parent / "shared" / "data" / "real"
W, H = 640, 480


def _similarity(eye_r, eye_l):
    d = np.subtract(eye_l, eye_r)
    iod = float(np.hypot(*d))
    c, s = d / iod
    return np.array([[c, -s], [s, c]]) * iod, 0.5 * (np.asarray(eye_r) + np.asarray(eye_l))


def _poly(img, pts, colour, thickness, closed=False):
    p = np.round(np.asarray(pts) * 16).astype(np.int32).reshape(-1, 1, 2)
    cv2.polylines(img, [p], closed, colour, thickness, cv2.LINE_AA, shift=4)


def draw_face(t: float, rng: np.random.Generator, skin_noise: np.ndarray):
    """One frame of the drawn face at time ``t`` in [0, 1]; returns (RGB image, truth)."""
    dx, dy = 6.0 * np.sin(2 * np.pi * t), 4.0 * np.sin(4 * np.pi * t)
    roll = 0.03 * np.sin(2 * np.pi * t)
    raise_ = 0.05 * np.sin(np.pi * t) ** 2  # brow raise, inter-eye units
    jaw = 0.06 * np.sin(np.pi * t) ** 2  # mouth opening
    centre = np.array([320.0 + dx, 200.0 + dy])
    half = 55.0
    eye_r = centre + half * np.array([-np.cos(roll), -np.sin(roll)])
    eye_l = centre + half * np.array([np.cos(roll), np.sin(roll)])
    R, o = _similarity(eye_r, eye_l)

    def tf(p, shift=(0.0, 0.0)):
        return (np.asarray(p) + shift) @ R.T + o

    img = np.empty((H, W, 3), np.uint8)
    img[:] = (110, 120, 135)
    face = tf(np.c_[0.95 * np.cos(np.linspace(0, 2 * np.pi, 80)),
                    0.45 + 1.55 * np.sin(np.linspace(0, 2 * np.pi, 80))])
    cv2.fillPoly(img, [np.round(face * 16).astype(np.int32)], (200, 160, 135), cv2.LINE_AA,
                 shift=4)
    hair = np.vstack([tf(TEMPLATE["hairline"], (0, -0.4 * raise_)),
                      tf([[0.9, -1.4], [-0.9, -1.4]])])
    cv2.fillPoly(img, [np.round(hair * 16).astype(np.int32)], (70, 45, 30), cv2.LINE_AA, shift=4)
    iod = 2 * half
    for side in ("l", "r"):
        _poly(img, tf(TEMPLATE[f"brow_{side}"], (0, -raise_)), (60, 40, 30),
              int(round(0.07 * iod)))
        _poly(img, tf(TEMPLATE[f"furrow_{side}"]), (150, 110, 95), 2)
        sx = 1 if side == "l" else -1
        nostril = tf([[0.11 * sx, 0.98 + 0.5 * jaw]])[0]
        cv2.ellipse(img, (int(round(nostril[0] * 16)), int(round(nostril[1] * 16))),
                    (int(0.05 * iod * 16), int(0.025 * iod * 16)), np.degrees(roll), 0, 360,
                    (40, 25, 25), -1, cv2.LINE_AA, shift=4)
    for e in (-0.5, 0.5):
        # eyes: a white almond, the lids opening a little with the brows, an iris
        t = np.linspace(0, 2 * np.pi, 60)
        almond = tf(np.c_[e + 0.2 * np.cos(t),
                          (0.07 + 0.2 * raise_) * np.sin(t) * (1 + 0.2 * np.cos(t))])
        inside = np.zeros((H, W), np.uint8)
        cv2.fillPoly(inside, [np.round(almond * 16).astype(np.int32)], 255, cv2.LINE_AA,
                     shift=4)
        eye = np.empty_like(img)
        eye[:] = (235, 235, 230)
        ctr = tf([[e, 0.0]])[0]
        cv2.circle(eye, (int(round(ctr[0] * 16)), int(round(ctr[1] * 16))),
                   int(round(0.08 * iod * 16)), (70, 50, 40), -1, cv2.LINE_AA, shift=4)
        wgt = (inside.astype(np.float32) / 255)[..., None]
        img = np.round(wgt * eye + (1 - wgt) * img).astype(np.uint8)
        _poly(img, almond, (90, 60, 50), 1, closed=True)
    mouth = TEMPLATE["upper_lip"]
    lower = TEMPLATE["lower_lip"] + [0, jaw]
    lip_poly = np.vstack([tf(mouth + [0, -0.09]), tf(lower[::-1])])
    cv2.fillPoly(img, [np.round(lip_poly * 16).astype(np.int32)], (170, 70, 70), cv2.LINE_AA,
                 shift=4)
    _poly(img, tf(mouth + [0, 0.5 * jaw]), (60, 20, 20), 2)
    _poly(img, tf(TEMPLATE["chin_boss"], (0, jaw)), (150, 110, 95), 2, closed=True)
    img = cv2.GaussianBlur(img, (0, 0), 0.8)
    noisy = img.astype(np.float32) * skin_noise[..., None] + rng.normal(0, 3, img.shape)
    img = np.clip(noisy, 0, 255).astype(np.uint8)
    brow_l, brow_r = tf(TEMPLATE["brow_l"], (0, -raise_)), tf(TEMPLATE["brow_r"], (0, -raise_))
    truth = {
        "brow_inner_l": brow_l[0], "brow_outer_l": brow_l[-1],
        "brow_inner_r": brow_r[0], "brow_outer_r": brow_r[-1],
        "mouth_corner_l": tf(mouth[-1:] + [0, 0.5 * jaw])[0],
        "mouth_corner_r": tf(mouth[:1] + [0, 0.5 * jaw])[0],
        "furrow_top_l": tf(TEMPLATE["furrow_l"][:1])[0],
        "furrow_top_r": tf(TEMPLATE["furrow_r"][:1])[0],
        "chin": tf([[0.0, 1.829 + jaw]])[0],
    }
    return img, truth, (eye_r, eye_l), (R, o)


def _track_fps(frames, layout, repeat):
    """Frames per second from the median time of one ``track`` call (first frame of each
    run excluded: it settles the layout). The median resists the spikes of a shared
    machine; the mean is reported too."""
    times = []
    last = None
    for _ in range(repeat):
        tracker = Tracker(layout)
        tracker.track(frames[0])
        results = []
        for f in frames[1:]:
            t0 = time.perf_counter()
            results.append(tracker.track(f))
            times.append(time.perf_counter() - t0)
        last = results
    return 1.0 / statistics.median(times), 1.0 / statistics.fmean(times), last


def _real_frames(path, n):
    return [cv2.cvtColor(cv2.resize(f, (W, H), interpolation=cv2.INTER_AREA),
                         cv2.COLOR_BGR2RGB) for f in read_frames(path, n)]


def run(quick: bool = False) -> list[Figure]:
    threads = cv2.getNumThreads()
    cv2.setNumThreads(1)  # "on one core": OpenCV's blur would otherwise use a pool
    try:
        return _run(quick)
    finally:
        cv2.setNumThreads(threads)


def _run(quick: bool) -> list[Figure]:
    n = 60 if quick else 200
    repeat = 3 if quick else 5
    rng = np.random.default_rng(0)
    skin = (1.0 + 0.04 * cv2.GaussianBlur(rng.normal(size=(H, W)).astype(np.float32),
                                          (0, 0), 3.0) * 3).astype(np.float32)
    frames, truths, sims = [], [], []
    for i in range(n):
        img, truth, eyes, sim = draw_face(i / (n - 1), rng, skin)
        frames.append(img)
        truths.append(truth)
        sims.append(sim)
        if i == 0:
            eyes0 = eyes
    layout = layout_from_eyes(*eyes0, (W, H))
    fps, fps_mean, results = _track_fps(frames, layout, repeat)
    errs = [np.hypot(*(np.asarray(r.fiducials[k]) - t[k])) for r, t in zip(results, truths[1:])
            for k in t]
    # head frame against the rigid motion: frame 0's tracked frame moved by the truth
    head0 = Tracker(layout).track(frames[0]).head
    R0, o0 = sims[0]
    h_err = []
    for r, (R, o) in zip(results, sims[1:]):
        M = R @ np.linalg.inv(R0)  # similarity from frame 0 to this frame
        origin = M @ (np.array([head0.x, head0.y]) - o0) + o
        scale = head0.scale * float(np.sqrt(abs(np.linalg.det(M))))
        roll = head0.roll + float(np.arctan2(M[1, 0], M[0, 0]))
        h_err.append((np.hypot(r.head.x - origin[0], r.head.y - origin[1]),
                      abs(r.head.scale / scale - 1) * 100, abs(r.head.roll - roll)))
    h_err = np.array(h_err)
    lost = sum(not r.success for r in results)
    iters = statistics.median(r.iterations for r in results)
    figures = [Figure("tracking", "synthetic 640x480", "frames per second", fps, "frame/s",
                      higher_is_better=True, target=300.0,
                      extra={"frames": n - 1, "median_iterations": iters,
                             "lost_frames": lost, "fps_from_mean_time": fps_mean}),
               Figure("tracking", "synthetic 640x480", "mean fiducial error", float(np.mean(errs)),
                      "px", higher_is_better=False,
                      extra={"fiducials": [k for k in FIDUCIAL_NAMES if k in truths[0]]}),
               Figure("tracking", "synthetic 640x480", "head frame origin error (max)",
                      float(h_err[:, 0].max()), "px", higher_is_better=False,
                      extra={"scale_error_percent_max": float(h_err[:, 1].max()),
                             "roll_error_rad_max": float(h_err[:, 2].max()),
                             "origin_error_px_median": float(np.median(h_err[:, 0])),
                             "head_sources": sorted({r.extra.get("head_source", "")
                                                     for r in results})})]
    if REAL.is_dir():
        for path in sorted(REAL.glob("*.mp4")):
            frames = _real_frames(path, 40 if quick else 150)
            if len(frames) < 3:
                continue
            try:
                layout = detect_layout(frames[0])
            except ValueError as exc:
                figures.append(Figure("tracking", f"real {path.stem}", "frames per second",
                                      float("nan"), "frame/s", higher_is_better=True,
                                      extra={"error": str(exc)}))
                continue
            fps, fps_mean, results = _track_fps(frames, layout, max(repeat // 2, 2))
            figures.append(Figure("tracking", f"real {path.stem}", "frames per second", fps,
                                  "frame/s", higher_is_better=True, target=300.0,
                                  extra={"frames": len(frames) - 1,
                                         "fps_from_mean_time": fps_mean,
                                         "lost_frames": sum(not r.success for r in results),
                                         "median_iterations": statistics.median(
                                             r.iterations for r in results)}))
    return figures


if __name__ == "__main__":
    from _harness import emit

    emit("tracking", run(quick="--quick" in sys.argv))
