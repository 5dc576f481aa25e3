"""The front door: ``import faceanalysis as fa`` gives the toolkit's main functions."""

import importlib
import subprocess
import sys

import pytest

import faceanalysis as fa


def test_every_exported_name_resolves_to_its_defining_module():
    for name, module in fa._EXPORTS.items():
        value = getattr(fa, name)
        assert value is getattr(importlib.import_module(module), name), name
        assert name in dir(fa)
    # what tab completion offers is the public names, not the module's own imports
    assert set(dir(fa)) == set(fa.__all__)


def test_the_readme_names_are_there():
    from faceanalysis.analysis.pipeline import analyze
    from faceanalysis.evaluation.scores import evaluate

    assert fa.analyze is analyze and fa.evaluate is evaluate
    for name in ("Analysis", "read_contractions", "resynthesize", "track"):
        assert callable(getattr(fa, name))


def test_unknown_names_raise_attribute_error():
    with pytest.raises(AttributeError, match="no attribute 'analyse'"):
        fa.analyse  # noqa: B018


def test_import_is_lazy():
    code = ("import sys, faceanalysis; "
            "print(any(m.startswith(('faceanalysis.analysis', 'synth', 'cv2')) "
            "for m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout.strip()
    assert out == "False"
