"""Flow: EPE of DIS/Farneback/TV-L1 vs exact flow, flow-step fps at 640x480, recognition.

Measured:

1. End-point error of the toolkit's three flow methods (:func:`faceanalysis.flow.dense.
   compute_flow`: DIS medium refined to full resolution, Farneback, TV-L1 with a pyramid deep
   enough for the motion) against the renderer's exact forward flow, frame to frame, on the
   non-occluded face pixels (eroded by 2 px) of the standard evaluation suite
   (:data:`faceanalysis.evaluation.suite.STANDARD_SEQUENCES`, its head motion, noise and light
   change), one identity (two sequences with ``--quick``).
2. Frames per second of the flow step of :func:`faceanalysis.flow.dense.face_flow` on 640x480
   video (stabilised crop, flow from the neutral frame, grid resampling), per method, with
   the default flow stabilisation (a coarse DIS flow to align the crop, then the method's
   flow) and with head-frame stabilisation (one flow per frame); for DIS, beside the same
   step aligned on the full-resolution flow; OpenCV on one thread.
3. Recognition accuracy over the seven classes on synthetic sequences of unseen identities
   with head motion, light change and noise (:func:`faceanalysis.flow.recognition.
   evaluate_recognition`; 10 identities, 2 with ``--quick``), confusion matrix in the JSON.
4. Flow validation on analysed synthetic sequences (:func:`faceanalysis.evaluation.validation.
   evaluate_validation`): mean cosine agreement of the input flow with the resynthesis of
   the joint estimate, of the flow estimate, and of the flow estimate shuffled in time.
"""

from __future__ import annotations

import time

import cv2
import numpy as np
from _harness import Figure, median_time

NAME = "flow"


def _epe_figures(quick: bool) -> list[Figure]:
    from faceanalysis.evaluation.suite import STANDARD_SEQUENCES, SUITE_SEEDS_START, SuiteConfig
    from faceanalysis.flow.dense import compute_flow
    from faceanalysis.flow.options import FLOW_METHODS
    from synth.render import synthesize

    cfg = SuiteConfig()
    seqs = STANDARD_SEQUENCES[:2] if quick else STANDARD_SEQUENCES
    frames = 10 if quick else 20
    errs = {m: [] for m in FLOW_METHODS}
    times = {m: [] for m in FLOW_METHODS}
    mags = []
    kernel = np.ones((5, 5), np.uint8)
    for kind, spec in seqs:
        kw = {"expression": spec} if kind == "expression" else {"au": spec}
        seq = synthesize(frames=frames, size=cfg.size, seed=SUITE_SEEDS_START,
                         head_motion=cfg.head_motion, noise=cfg.noise,
                         illumination=cfg.illumination, **kw)
        for t in range(len(seq.images) - 1):
            a = cv2.cvtColor(seq.images[t], cv2.COLOR_RGB2GRAY)
            b = cv2.cvtColor(seq.images[t + 1], cv2.COLOR_RGB2GRAY)
            m = cv2.erode((seq.mask[t] & ~seq.occluded[t]).astype(np.uint8),
                          kernel).astype(bool)
            gt = seq.flow[t]
            mags.append(float(np.linalg.norm(gt, axis=2)[m].mean()))
            for meth in FLOW_METHODS:
                t0 = time.perf_counter()
                fl = compute_flow(a, b, meth, max_motion=float(np.abs(gt).max()) + 2)
                times[meth].append(time.perf_counter() - t0)
                errs[meth].append(float(np.linalg.norm(fl - gt, axis=2)[m].mean()))
    return [Figure(NAME, f"EPE {meth} vs exact flow, standard suite {cfg.size}px",
                   "end-point error", float(np.mean(errs[meth])), "px", False,
                   extra={"sequences": [f"{k}:{s}" for k, s in seqs],
                          "frame_pairs": len(errs[meth]),
                          "median_epe_px": float(np.median(errs[meth])),
                          "mean_true_flow_px": float(np.mean(mags)),
                          "median_s_per_pair": float(np.median(times[meth])),
                          "head_motion": cfg.head_motion, "noise": cfg.noise,
                          "illumination": cfg.illumination})
            for meth in FLOW_METHODS]


def _fps_figures(quick: bool) -> list[Figure]:
    from faceanalysis.flow.dense import _FlowStep
    from faceanalysis.flow.grid import FaceGrid
    from faceanalysis.flow.options import FLOW_METHODS
    from synth.model import FaceModel
    from synth.render import Renderer, default_camera, paint_skin_texture
    from synth.render.camera import HeadPose

    model = FaceModel.default()
    mesh = model.mesh
    cam = default_camera(640, 480)
    r = Renderer(mesh, texture=paint_skin_texture(mesh, 0), camera=cam)
    model.set_contractions({"zygomaticus_major_l": 0.8, "zygomaticus_major_r": 0.8})
    v1 = model.equilibrate()
    model.reset()
    model.set_contractions(None)
    v0 = model.equilibrate()
    img0 = cv2.cvtColor(r.render(v0).image, cv2.COLOR_RGB2BGR)
    img1 = cv2.cvtColor(r.render(v1, pose=HeadPose(roll=2.0, translation=(0.3, 0.1, 0))
                                 ).image, cv2.COLOR_RGB2BGR)
    from faceanalysis.flow.templates import _tracked_head

    head = _tracked_head(cv2.cvtColor(img0, cv2.COLOR_BGR2RGB))   # trackers' head frame
    if head is None:
        raise RuntimeError("the tracker found no face in the 640x480 render")
    grid = FaceGrid()
    cv2.setNumThreads(1)
    out = []
    repeat = 3 if quick else 7
    try:
        for meth in FLOW_METHODS:
            for stab in ("flow", "head"):
                if meth == "tvl1" and quick and stab == "flow":
                    continue
                step = _FlowStep(img0, head, grid, meth, None, True, stabilization=stab)
                t = _step_time(step, img1, head, repeat if meth != "tvl1" else 2)
                peer = ratio = None
                if meth == "dis" and stab == "flow":
                    full = _FlowStep(img0, head, grid, meth, None, True, stabilization=stab)
                    full.align_level = 0                # aligned on the full-resolution flow
                    t_full = _step_time(full, img1, head, repeat)
                    out.append(Figure(NAME, "flow step dis (flow stabilisation, aligned on the "
                                      "full-resolution flow) 640x480", "frames per second",
                                      1.0 / t_full, "frames/s", True, extra={"threads": 1}))
                    peer, ratio = "the alignment on the full-resolution flow", t_full / t
                out.append(Figure(NAME, f"flow step {meth} ({stab} stabilisation) 640x480",
                                  "frames per second", 1.0 / t, "frames/s", True, peer=peer,
                                  ratio=ratio,
                                  extra={"crop_px_per_unit": step.crop.px_per_unit,
                                         "crop_size": list(step.crop.size),
                                         "grid": grid.as_dict(), "threads": 1}))
    finally:
        cv2.setNumThreads(-1)
    return out


def _step_time(step, img1, head, repeat: int) -> float:
    """Median seconds of one flow step from ``step``'s reference to ``img1``."""
    def once():
        step.prev = None
        step(img1, head)

    return median_time(once, repeat=repeat, number=1)


def _recognition_figures(quick: bool) -> list[Figure]:
    from faceanalysis.flow.recognition import evaluate_recognition
    from faceanalysis.flow.templates import default_templates

    ids = range(100, 102) if quick else range(100, 110)
    t0 = time.perf_counter()
    r = evaluate_recognition(ids, templates=default_templates(),
                             frames=24 if quick else 30)
    conf = r["confusion"]
    return [Figure(NAME, f"recognition, 7 classes, {len(r['identities'])} unseen identities",
                   "accuracy", 100.0 * r["accuracy"], "%", True, target=98.0,
                   extra={"confusion": {str(k): {str(c): int(v) for c, v in row.items()}
                                        for k, row in conf.iterrows()},
                          "sequences": int(len(r["results"])), "frames": r["frames"],
                          "head_motion": r["head_motion"],
                          "illumination": r["illumination"], "noise": r["noise"],
                          "elapsed_s": time.perf_counter() - t0})]


def _validation_figures(quick: bool) -> list[Figure]:
    from faceanalysis.evaluation.validation import evaluate_validation
    from faceanalysis.flow.templates import default_templates

    ids = range(101, 102) if quick else range(101, 104)
    exprs = ("happiness", "surprise") if quick else ("happiness", "surprise", "anger",
                                                     "sadness")
    r = evaluate_validation(ids, exprs, templates=default_templates())
    s = r["summary"]
    out = []
    for key, label, target in (("cosine_joint", "resynthesis of the joint estimate", None),
                               ("cosine_flow", "resynthesis of the flow estimate", 0.9),
                               ("cosine_shuffled", "flow estimate shuffled in time", None)):
        out.append(Figure(NAME, f"validation: input vs {label}", "mean cosine on face mask",
                          s[key], "", True, target=target,
                          extra={"sequences": s["sequences"],
                                 "mean_epe_head_units": s[key.replace("cosine", "epe")]}))
    return out


def run(quick: bool) -> list[Figure]:
    return (_epe_figures(quick) + _fps_figures(quick) + _recognition_figures(quick)
            + _validation_figures(quick))
