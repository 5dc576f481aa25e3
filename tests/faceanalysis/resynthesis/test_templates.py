"""Flow templates for a subject: the command's library function."""

import numpy as np
import pytest

from faceanalysis.flow.templates import FlowTemplates
from faceanalysis.resynthesis.templates import write_template_set


@pytest.mark.slow
def test_a_subjects_templates_come_from_its_own_model(subject, tmp_path):
    root, _ = subject
    written = write_template_set(tmp_path / "tpl", subject=root / "analysis", size=128,
                                 n_steps=2, previews=False)
    generic = FlowTemplates.load(written["templates"])
    personal = FlowTemplates.load(written["personalised_templates"])
    assert personal.meta["personalisation"] == "model"
    assert personal.controls == generic.controls
    # another face moves otherwise: the subject's templates are not the generic ones
    assert not np.allclose(personal.control, generic.control, equal_nan=True)


def test_a_missing_subject_is_named_before_any_work(tmp_path):
    with pytest.raises(FileNotFoundError, match="no contractions.csv"):
        write_template_set(tmp_path / "tpl", subject=tmp_path / "nowhere")
    assert not (tmp_path / "tpl").exists()
