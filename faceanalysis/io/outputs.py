"""Output file names, and the atomic writers (:mod:`synth.files`) the toolkit writes them with:
an interrupted run never leaves a file that looks complete."""

from __future__ import annotations

from synth.files import atomic_path, prepare_output_dir, write_bytes_atomic, write_text_atomic

__all__ = ["atomic_path", "prepare_output_dir", "write_bytes_atomic", "write_text_atomic",
           "CONTRACTIONS_CSV", "ANALYSIS_JSON", "CONTRACTIONS_PNG", "OVERLAY_MP4",
           "VALIDATION_CSV", "VALIDATION_PNG", "EVALUATION_JSON", "REPORT_JSON", "REPORT_MD",
           "REPORT_PNG", "SUMMARY_CSV"]

#: File names of an analysis folder (``faceanalysis analyze VIDEO -o OUT``).
CONTRACTIONS_CSV = "contractions.csv"
ANALYSIS_JSON = "analysis.json"
CONTRACTIONS_PNG = "contractions.png"
OVERLAY_MP4 = "overlay.mp4"
#: ``faceanalysis validate`` adds these to the analysis folder.
VALIDATION_CSV = "validation.csv"
VALIDATION_PNG = "validation.png"
#: ``faceanalysis demo``'s score of its analysis.
EVALUATION_JSON = "evaluation.json"
#: ``faceanalysis evaluate --suite``'s report.
REPORT_JSON = "report.json"
REPORT_MD = "report.md"
REPORT_PNG = "report.png"
#: ``faceanalysis batch``'s table of every video.
SUMMARY_CSV = "summary.csv"
