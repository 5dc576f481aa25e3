"""Output file names, and the atomic writers (:mod:`synth.files`) the toolkit writes them with:
an interrupted run never leaves a file that looks complete."""

from __future__ import annotations

from synth.files import (
    atomic_path,
    first_missing_folder,
    output_dir,
    partial_files,
    prepare_output_dir,
    remove_new_folders,
    write_bytes_atomic,
    write_text_atomic,
)

__all__ = ["atomic_path", "first_missing_folder", "output_dir", "partial_files",
           "prepare_output_dir", "remove_new_folders", "write_bytes_atomic", "write_text_atomic",
           "CONTRACTIONS_CSV", "ANALYSIS_JSON", "CONTRACTIONS_PNG", "OVERLAY_MP4", "OVERLAY_AVI",
           "VALIDATION_CSV", "VALIDATION_PNG", "EVALUATION_JSON", "REPORT_JSON", "REPORT_MD",
           "REPORT_PNG", "SUMMARY_CSV", "ANALYSIS_OUTPUTS"]

#: File names of an analysis folder (``faceanalysis analyze VIDEO -o OUT``).
CONTRACTIONS_CSV = "contractions.csv"
ANALYSIS_JSON = "analysis.json"
CONTRACTIONS_PNG = "contractions.png"
OVERLAY_MP4 = "overlay.mp4"
#: The overlay where OpenCV has no MP4 encoder.
OVERLAY_AVI = "overlay.avi"
#: ``faceanalysis validate`` adds these to the analysis folder.
VALIDATION_CSV = "validation.csv"
VALIDATION_PNG = "validation.png"
#: Every file of the toolkit's that an analysis folder may hold: a rerun with ``overwrite``
#: removes those it did not write again (an earlier run's overlay, a validation of the
#: earlier results), never any other file.
ANALYSIS_OUTPUTS = (CONTRACTIONS_CSV, ANALYSIS_JSON, CONTRACTIONS_PNG, OVERLAY_MP4, OVERLAY_AVI,
                    VALIDATION_CSV, VALIDATION_PNG)
#: ``faceanalysis demo``'s score of its analysis.
EVALUATION_JSON = "evaluation.json"
#: ``faceanalysis evaluate --suite``'s report.
REPORT_JSON = "report.json"
REPORT_MD = "report.md"
REPORT_PNG = "report.png"
#: ``faceanalysis batch``'s table of every video.
SUMMARY_CSV = "summary.csv"
