"""Flow templates for a command line: the generic face's, one subject's and one synthetic
identity's, written into one folder (``faceanalysis templates``).

A subject's templates come from the face model personalised to the subject in 3-D
(:func:`faceanalysis.resynthesis.personalize.personal_model`) where that works, and
otherwise from the generic templates warped onto the subject's neutral fiducials in 2-D
(:func:`faceanalysis.flow.personalize.personalize_from_table`).
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import pandas as pd

from faceanalysis.flow.personalize import personalize_from_table
from faceanalysis.flow.templates import make_templates, write_templates
from faceanalysis.io.outputs import ANALYSIS_JSON, CONTRACTIONS_CSV, output_dir
from faceanalysis.resynthesis.personalize import personal_model

__all__ = ["write_template_set"]


def _neutral_frame(csv: Path, table: pd.DataFrame) -> int:
    """The analysis's neutral frame (``analysis.json``), else its first tracked frame."""
    meta_path = csv.parent / ANALYSIS_JSON
    if meta_path.is_file():
        neutral = json.loads(meta_path.read_text()).get("parameters", {}).get("neutral_frame")
        if neutral is not None:
            return int(neutral)
    ok = table["success"].to_numpy() == 1 if "success" in table else None
    if ok is None or not ok.any():
        raise ValueError(f"{csv}: no tracked frame to personalise on")
    return int(table["frame"].to_numpy()[ok.argmax()])


def write_template_set(output: str | os.PathLike, *, subject=None, identity: int | None = None,
                       size: int = 256, n_steps: int = 6, source: str = "exact",
                       previews: bool = True, overwrite: bool = False) -> dict[str, Path]:
    """Make and write the generic face's flow templates, and optionally a subject's and a
    synthetic identity's.

    Parameters
    ----------
    output : path-like
        Folder to write into (refused when it holds files, unless ``overwrite``).
    subject : path-like, optional
        An analysis folder or its ``contractions.csv``: also write the templates of that
        subject (``personalised_*``).
    identity : int, optional
        Also write the templates of the synthetic identity with this seed.
    size, n_steps, source
        Passed to :func:`faceanalysis.flow.templates.make_templates`.
    previews : bool, keyword-only
        Also write preview pictures.
    overwrite : bool, keyword-only

    Returns
    -------
    dict
        Name -> path of every file written.
    """
    from synth.face_shape import FaceShape
    from synth.model import FaceModel

    csv = None
    if subject is not None:
        subject = Path(subject)
        csv = subject / CONTRACTIONS_CSV if subject.is_dir() else subject
        if not csv.is_file():
            raise FileNotFoundError(f"{csv}: no contractions.csv for the subject")
    with output_dir(output, overwrite=overwrite) as out:
        options = {"size": size, "n_steps": n_steps, "source": source}
        generic = make_templates(FaceModel.default(), **options)
        written = write_templates(generic, out, name="generic", previews=previews)
        if csv is not None:
            personal = personal_model(csv.parent, FaceModel.default())
            if personal is not None:
                pers = make_templates(personal, **options)
                pers.meta.update(personalised=True, personalisation="model")
            else:
                table = pd.read_csv(csv)
                pers = personalize_from_table(generic, table, _neutral_frame(csv, table))
                if not pers.meta.get("personalised"):
                    raise ValueError(f"{csv}: the neutral frame's fiducials are missing")
                pers.meta["personalisation"] = "warp"
            written.update({f"personalised_{k}": v for k, v in write_templates(
                pers, out, name="personalised", previews=previews).items()})
        if identity is not None:
            model = FaceModel.build(FaceShape.random(identity))
            tpl = make_templates(model, texture_seed=identity, **options)
            tpl.meta["identity"] = int(identity)
            name = f"identity_{identity}"
            written.update({f"{name}_{k}": v for k, v in write_templates(
                tpl, out, name=name, previews=previews).items()})
        return written
