"""The standard suite: analyse synthetic video whose answer is known.

The face model renders sequences from known contractions (:mod:`synth.render`); the
analysis estimates them back; :mod:`faceanalysis.evaluation.scores` compares the two.
:func:`run_suite` renders the standard suite (the six primary expressions and mixed
action-unit scripts over several identities, with head motion, sensor noise and
illumination change), analyses every sequence with each estimator and pools the scores.

With ``faces`` (a folder of frontal, neutral photographs) it also renders the same scripts
on each photographed person (:mod:`faceanalysis.resynthesis.photo`: the model fitted to the
photograph and textured with it) and reports that photo suite beside the procedural one,
scored the same way with the same estimators: the procedural faces are drawn for the
trackers, the photographed ones look like the video a user brings.
"""

from __future__ import annotations

import json
import logging
import os
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from faceanalysis.evaluation.scores import compare, format_table, pool, public
from faceanalysis.io.outputs import (
    REPORT_JSON,
    REPORT_MD,
    REPORT_PNG,
    atomic_path,
    output_dir,
    write_text_atomic,
)

log = logging.getLogger(__name__)

#: The standard suite: the six primary expressions and mixed action-unit scripts.
STANDARD_SEQUENCES: tuple[tuple[str, str], ...] = (
    ("expression", "happiness"), ("expression", "sadness"), ("expression", "surprise"),
    ("expression", "fear"), ("expression", "anger"), ("expression", "disgust"),
    ("au", "1:0.9,2:0.7"), ("au", "4:0.8,15:0.6"), ("au", "12:0.7,26:0.6"),
    ("au", "9:0.8,2:0.5"), ("au", "15:0.9,1:0.5"),
)

#: Identity seeds of the suite; seed 0 is the generic face, which is left out so that
#: the suite tests faces the response table was not made from.
SUITE_SEEDS_START = 101


def script_kwargs(kind: str, spec: str) -> dict:
    """Keyword arguments of the renderer's timeline for one entry of a suite's sequences
    (``("expression", name)`` or ``("au", script)``)."""
    return {"expression": spec} if kind == "expression" else {"au": spec}


@dataclass(frozen=True)
class SuiteConfig:
    """What the standard suite renders."""

    identities: int = 10
    frames: int = 30
    size: int = 256
    head_motion: float = 0.3
    noise: float = 2.0
    illumination: float = 0.3
    sequences: tuple[tuple[str, str], ...] = STANDARD_SEQUENCES
    seed_start: int = SUITE_SEEDS_START
    #: Photographs of the photo suite (empty: none); see :func:`photographs`.
    faces: tuple[str, ...] = ()
    #: Tracker of the analyses: the snakes of 004, which the procedural faces are drawn
    #: for; 'landmarks' (:func:`~faceanalysis.analysis.pipeline.analyze`'s default, which
    #: real faces need) runs the suite as a user's video is analysed.
    tracker: str = "snakes"

    def __post_init__(self):
        if self.identities < 1 or self.frames < 3 or self.size < 64:
            raise ValueError("the suite needs identities >= 1, frames >= 3 and size >= 64")
        if self.tracker not in ("snakes", "landmarks"):
            raise ValueError(f"tracker must be 'snakes' or 'landmarks', got {self.tracker!r}")


def photographs(folder: str | os.PathLike, *, limit: int | None = None) -> tuple[str, ...]:
    """The image files in ``folder`` (sorted by name; the first ``limit``): one frontal,
    neutral photograph per person for the photo suite.

    Raises
    ------
    FileNotFoundError
        No such folder.
    ValueError
        It holds no image.
    """
    from faceanalysis.io.video import IMAGE_SUFFIXES

    path = Path(folder)
    if not path.is_dir():
        raise FileNotFoundError(f"{path}: no such folder of photographs")
    found = sorted(str(p) for p in path.iterdir()
                   if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES)
    if not found:
        raise ValueError(f"{path}: no photographs in it ({', '.join(IMAGE_SUFFIXES)})")
    return tuple(found[:limit] if limit else found)


def _label(kind: str, spec: str) -> str:
    return spec if kind == "expression" else "au_" + spec.replace(":", "-").replace(",", "_")


def _identities(config: SuiteConfig) -> list[tuple[str, dict, object]]:
    """(suite, identity entry, render function(folder, seed, **script)) per identity."""
    from synth.render.sequence import render_sequence

    common = dict(frames=config.frames, head_motion=config.head_motion, noise=config.noise,
                  illumination=config.illumination, flow=False, overwrite=True)
    out = []
    for i in range(config.identities):
        seed = config.seed_start + i

        def procedural(d, seed=seed, **script):
            return render_sequence(d, size=config.size, seed=seed, **common, **script)

        out.append(("procedural", {"identity": seed, "name": f"id{seed:03d}"}, procedural))
    for i, photo in enumerate(config.faces):
        from faceanalysis.resynthesis.photo import photo_face

        # fitted up front: a photograph without a usable face stops the suite before
        # anything is rendered, naming the file
        face = photo_face(photo, size=config.size)
        name = "photo_" + Path(photo).stem
        out.append(("photo", {"identity": Path(photo).name, "name": name},
                    _photo_renderer(face, config.seed_start + i, common)))
    return out


def _photo_renderer(face, seed: int, common: dict):
    """Render function of one photographed person."""
    def render(d, **script):
        from faceanalysis.resynthesis.photo import render_face

        return render_face(face, d, seed=seed, **common, **script)

    return render


def run_suite(output: str | os.PathLike, *, config: SuiteConfig = SuiteConfig(),
              estimators=("joint", "tw93", "flow"), overwrite: bool = False,
              progress: bool = False, keep_videos: bool = True) -> dict:
    """Render the standard suite, analyse it with each estimator and write the report.

    Writes into ``output``: ``sequences/<id>/`` (video + ground truth + one
    ``contractions_<estimator>.csv`` each, unless ``keep_videos`` is false),
    ``report.json``, ``report.md`` and ``report.png``.

    Returns
    -------
    dict
        The report: per estimator, pooled scores; per sequence, the joint scores.
    """
    from faceanalysis.analysis.pipeline import analyze, reestimate

    with output_dir(output, overwrite=overwrite) as out:
        seq_dir = out / "sequences"
        suites = ("procedural", "photo") if config.faces else ("procedural",)
        per_est = {su: {e: [] for e in estimators} for su in suites}
        sequences = {su: [] for su in suites}
        jobs = [(su, ident, render, kind, spec) for su, ident, render in _identities(config)
                for kind, spec in config.sequences]
        bar = None
        if progress:
            from tqdm import tqdm

            bar = tqdm(total=len(jobs), desc="suite", unit="seq", file=sys.stderr, leave=False)
        t0 = time.perf_counter()
        failures = []
        for su, ident, render, kind, spec in jobs:
            d = seq_dir / f"{ident['name']}_{_label(kind, spec)}"
            entry = {"sequence": d.name, "identity": ident["identity"], "kind": kind,
                     "spec": spec}
            render(d, **script_kwargs(kind, spec))
            video = next(p for p in d.iterdir() if p.stem == "video")
            truth = pd.read_csv(d / "truth.csv")
            try:
                base = analyze(video, tracker=config.tracker)
            except (ValueError, RuntimeError) as exc:
                failures.append({**entry, "suite": su, "error": str(exc)})
                log.warning("suite: %s failed: %s", d.name, exc)
                if bar is not None:
                    bar.update(1)
                continue
            for est in estimators:
                if est == base.metadata["parameters"]["estimator"]:
                    a = base
                elif est == "flow":
                    from faceanalysis.estimation.flow import reestimate_flow

                    a = reestimate_flow(base, video)
                else:
                    a = reestimate(base, est)
                if keep_videos:
                    from faceanalysis.io.table import write_contractions

                    write_contractions(a.table, d / f"contractions_{est}.csv")
                rep = compare(truth, a.table)
                per_est[su][est].append(rep)
                entry[est] = {k: v for k, v in public(rep).items() if k != "controls"}
            sequences[su].append(entry)
            if not keep_videos:
                video.unlink()
            if bar is not None:
                bar.update(1)
        if bar is not None:
            bar.close()
        if not any(r for su in suites for r in per_est[su].values()):
            raise RuntimeError("every sequence of the suite failed; see the log")
        pooled = {su: {e: pool(r) for e, r in per_est[su].items() if r} for su in suites}
        report = {
            "suite": {**{k: v for k, v in config.__dict__.items()
                         if k not in ("sequences", "faces")},
                      "sequences": [list(s) for s in config.sequences]},
            "estimators": {e: public(p) for e, p in pooled["procedural"].items()},
            "sequences": sequences["procedural"],
            "failures": failures,
        }
        md = f"# Closed-loop evaluation\n\nTracker: {config.tracker}.\n\n"
        if config.faces:
            report["photo"] = {"faces": list(config.faces),
                               "estimators": {e: public(p)
                                              for e, p in pooled["photo"].items()},
                               "sequences": sequences["photo"]}
            md += "## Procedural faces\n\n"
        if pooled["procedural"]:
            md += format_table(pooled["procedural"]) + "\n"
        if config.faces:
            md += (f"\n## Photographed faces ({len(config.faces)} people)\n\n"
                   + (format_table(pooled["photo"]) if pooled["photo"]
                      else "every sequence failed") + "\n")
        report["elapsed_s"] = time.perf_counter() - t0
        write_text_atomic(out / REPORT_JSON, json.dumps(report, indent=1) + "\n")
        write_text_atomic(out / REPORT_MD, md)
        plot_report(pooled["procedural"] or pooled.get("photo"), out / REPORT_PNG,
                    photo=pooled.get("photo") if pooled["procedural"] else None)
        return report


def plot_report(pooled: dict[str, dict], path, *, photo: dict[str, dict] | None = None
                ) -> Path:
    """Bar chart of per-control RMSE and r for each estimator (and each estimator on the
    photographed faces, hatched, when ``photo`` is given)."""
    from matplotlib.figure import Figure

    if photo:
        pooled = {**pooled, **{f"{n} (photo)": p for n, p in photo.items()}}
    names = list(pooled)
    controls = [c for c in pooled[names[0]]["controls"]
                if (pooled[names[0]]["controls"][c].get("truth_max") or 0) > 1e-6]
    fig = Figure(figsize=(10, 6), constrained_layout=True)
    axes = fig.subplots(2, 1, sharex=True)
    x = np.arange(len(controls))
    width = 0.8 / max(len(names), 1)
    for k, n in enumerate(names):
        rm = [pooled[n]["controls"][c]["rmse"] or 0 for c in controls]
        rr = [pooled[n]["controls"][c]["r"] or 0 for c in controls]
        hatch = "//" if n.endswith("(photo)") else None
        axes[0].bar(x + k * width, rm, width, label=n, hatch=hatch)
        axes[1].bar(x + k * width, rr, width, label=n, hatch=hatch)
    axes[0].axhline(0.05, color="k", lw=0.8, ls="--")
    axes[1].axhline(0.95, color="k", lw=0.8, ls="--")
    axes[0].set_ylabel("RMSE")
    axes[1].set_ylabel("Pearson r")
    axes[1].set_ylim(0, 1.02)
    axes[1].set_xticks(x + width * (len(names) - 1) / 2, controls, rotation=60, ha="right",
                       fontsize=8)
    axes[0].legend()
    axes[0].set_title("Closed-loop evaluation on the synthetic suite")
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=150)
    return Path(path)
