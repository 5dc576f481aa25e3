"""Resynthesis: frames/s at 256x256 including per-frame equilibrium and rendering (one core).

A synthetic subject (identity 101, happiness, 30 frames at 256x256; 16 with ``--quick``) is
rendered and analysed once; its estimated contraction series then drives the face model
through :func:`faceanalysis.resynthesis.pipeline.resynthesize`. The figure is the time per frame of
setting the contractions, relaxing the lattice to equilibrium (warm-started from the
previous frame, default tolerance) and rendering the frame, as frames/s (target: 100, i.e.
real time at the analysis's own scale with room to spare), from the median wall time per
frame and from this process's CPU time (the honest one-core figure when other jobs share
the machine). Cases: the generic model (textured, plain, wireframe with the muscles drawn),
the personalised model (warped to the subject's neutral frame and textured with it), and
the generic model driven by the smooth ground-truth series (the estimated series is noisier
from frame to frame, so each equilibrium costs more). Also reported: the whole run with
video encoding (side by side with the plot strip), the one-off cost of building the
personalised model and its landmark error. Everything runs on one core.

Round trip (quality, not speed): the six primary expressions rendered on identity 101 (30
frames, 256x256, no degradation; ``--quick``: happiness and surprise), analysed, and
resynthesised with the same identity's model in the tracked head frame: mean distance in px
between the resynthesised and the true fiducials (target 1.5 px); also with the generic model
personalised to the subject instead of the true identity.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import statistics  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

from _harness import Figure  # noqa: E402

NAME = "resynth"
TARGET_FPS = 100.0


def _median_fps(res, passes: int) -> tuple[float, float, float]:
    """Frames/s over ``passes`` runs: from the median wall time per frame, from the median
    wall time of a run, and from the median CPU time of a run (this process, one thread:
    what one core delivers when other jobs share the machine)."""
    per_frame, totals, cpu, n = [], [], [], 0
    for _ in range(passes):
        t0, c0 = time.perf_counter(), time.process_time()
        secs = [st.seconds for st in res.states()]
        totals.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
        per_frame.extend(secs)
        n = len(secs)
    return (1.0 / statistics.median(per_frame), n / statistics.median(totals),
            n / statistics.median(cpu))


def run(quick: bool) -> list[Figure]:
    import cv2
    import pandas as pd

    from faceanalysis.analysis.pipeline import analyze
    from faceanalysis.io.table import MUSCLES
    from faceanalysis.resynthesis.personalize import personalize
    from faceanalysis.resynthesis.pipeline import resynthesize
    from synth.model import FaceModel
    from synth.render.sequence import render_sequence

    cv2.setNumThreads(1)
    try:
        import numba

        numba.set_num_threads(1)
    except (ImportError, ValueError):
        pass
    frames = 16 if quick else 30
    passes = 2 if quick else 4
    out: list[Figure] = []
    with tempfile.TemporaryDirectory() as tmp:
        files = render_sequence(Path(tmp) / "input", frames=frames, size=256, seed=101,
                                expression="happiness", flow=False)
        analysis = analyze(files["video"], tracker="snakes",
                           tracker_options={"brow_mid": 0.556})
        truth = pd.read_csv(files["truth"])
        model = FaceModel.default()
        t0 = time.perf_counter()
        subject = personalize(analysis, model=model)
        t_personal = time.perf_counter() - t0
        smooth = analysis.table.copy()
        smooth[[*MUSCLES, "jaw_rotation"]] = truth[[*MUSCLES, "jaw_rotation"]].to_numpy()
        cases = [
            ("generic textured", analysis, {}),
            ("generic plain", analysis, {"shading": "plain"}),
            ("generic wireframe", analysis, {"shading": "wireframe"}),
            ("personalised textured", analysis, {"subject": subject}),
            ("generic textured, smooth ground-truth drive", smooth, {}),
        ]
        for label, source, kw in cases:
            res = resynthesize(source, model=model, size=256, **kw)
            fps, overall, cpu = _median_fps(res, passes)
            out.append(Figure(NAME, f"{label} 256x256", "frames/s (median frame, wall)", fps,
                              "frames/s", True, target=TARGET_FPS,
                              extra={"frames": frames, "overall_fps": overall,
                                     "tolerance_cm": res.tol}))
            out.append(Figure(NAME, f"{label} 256x256", "frames/s (CPU time, one core)", cpu,
                              "frames/s", True, target=TARGET_FPS))
        # whole run to a file: side by side, plot strip, encoding
        t0 = time.perf_counter()
        res = resynthesize(analysis, model=model, subject=subject, side_by_side=True,
                           output=Path(tmp) / "sbs.mp4")
        elapsed = time.perf_counter() - t0
        out.append(Figure(NAME, "personalised side-by-side video, whole run", "frames/s",
                          frames / elapsed, "frames/s", True,
                          extra={"frames": frames, "seconds": elapsed}))
        out.append(Figure(NAME, "personalised model: warp + lattice + muscles", "seconds",
                          t_personal, "s", False))
        p = res.report["personalisation"]
        out.append(Figure(NAME, "personalisation landmark error", "mean px",
                          p["landmark_error_px"]["mean"], "px", False, target=1.0))
        out.append(Figure(NAME, "sequence photometric difference (personalised)",
                          "mean abs grey", res.report["frame_comparison"]["mean_mae_grey"],
                          "grey levels", False))
    out += _round_trip_figures(quick)
    return out


def _round_trip_figures(quick: bool) -> list[Figure]:
    from faceanalysis.evaluation.roundtrip import round_trip

    expressions = (("happiness", "surprise") if quick else
                   ("happiness", "sadness", "surprise", "fear", "anger", "disgust"))
    cases = [(101, e) for e in expressions]
    out = []
    for personalised in (False, True):
        table = round_trip(cases, frames=30, personalised=personalised)
        model = "generic personalised" if personalised else "same identity"
        for _, row in table.iterrows():
            out.append(Figure(NAME, f"round trip {row['expression']} ({model})",
                              "fiducial error", float(row["fiducial_error_px"]), "px", False,
                              target=1.5 if not personalised else None,
                              extra={"frames": int(row["frames"]),
                                     "apex_error_px": float(row["apex_error_px"])}))
        out.append(Figure(NAME, f"round trip mean ({model})", "fiducial error",
                          float(table["fiducial_error_px"].mean()), "px", False,
                          target=1.5 if not personalised else None))
    return out

