"""The demo: render a synthetic expression, analyse it, and score the result.

Needs no user data: the face model renders the input, so the true contractions are
known and the demo can say how close the analysis came.
"""

from __future__ import annotations

import json
import logging
import os
from pathlib import Path

from faceanalysis.io.logs import quiet_logger
from faceanalysis.io.outputs import (
    ANALYSIS_JSON,
    CONTRACTIONS_CSV,
    CONTRACTIONS_PNG,
    EVALUATION_JSON,
    OVERLAY_MP4,
    output_dir,
    write_text_atomic,
)


def run_demo(output: str | os.PathLike, *, expression: str = "surprise", frames: int = 48,
             size: int = 256, seed: int = 7, overwrite: bool = False,
             progress: bool = False, compare_snakes: bool = True) -> dict[str, Path]:
    """Render ``expression`` on a synthetic identity, analyse the video, compare with truth.

    Writes ``OUT/input/`` (``video.mp4`` and its ground truth), ``OUT/analysis/``
    (``contractions.csv``, ``analysis.json``, ``contractions.png``, ``overlay.mp4``: the
    analysis a user's video gets, :func:`~faceanalysis.analysis.pipeline.analyze`'s
    defaults) and ``OUT/evaluation.json`` (its scores; with ``compare_snakes``, under
    ``"snakes"`` also those of the snakes of 004 on the same video, which these rendered
    faces are drawn for: they are more precise here, and lose real faces).

    Returns
    -------
    dict
        Paths of the main files, by name.
    """
    from faceanalysis.analysis.pipeline import analyze, analyze_to_folder
    from faceanalysis.evaluation.scores import compare, public
    from synth.render.sequence import render_sequence

    with output_dir(output, overwrite=overwrite) as out:
        files = render_sequence(out / "input", overwrite=overwrite, expression=expression,
                                frames=frames, size=size, seed=seed, head_motion=0.2, noise=1.0,
                                flow=False)
        analysis_dir = out / "analysis"
        analyze_to_folder(files["video"], analysis_dir, overwrite=overwrite, overlay=True,
                          quiet=not progress)
        report = public(compare(files["truth"], analysis_dir))
        if compare_snakes:
            # a comparison, not the analysis: its warnings were the default's to give
            with quiet_logger("faceanalysis", logging.ERROR):
                snakes = analyze(files["video"], tracker="snakes")
            report["snakes"] = public(compare(files["truth"], snakes.table))
        evaluation = write_text_atomic(out / EVALUATION_JSON, json.dumps(report, indent=1) + "\n")
        return {"video": Path(files["video"]), "truth": Path(files["truth"]),
                "contractions": analysis_dir / CONTRACTIONS_CSV,
                "plot": analysis_dir / CONTRACTIONS_PNG, "overlay": analysis_dir / OVERLAY_MP4,
                "analysis": analysis_dir / ANALYSIS_JSON, "evaluation": evaluation,
                "_report": report}
