"""The front door: ``from synth import FaceModel`` and the renderer, loaded on first use."""

import importlib
import subprocess
import sys

import pytest

import synth


def test_every_exported_name_resolves_to_its_defining_module():
    for name, module in synth._EXPORTS.items():
        assert getattr(synth, name) is getattr(importlib.import_module(module), name), name
    assert set(dir(synth)) == set(synth.__all__)


def test_unknown_names_raise_attribute_error():
    with pytest.raises(AttributeError, match="no attribute 'FaceModle'"):
        synth.FaceModle  # noqa: B018


def test_a_module_of_the_package_loads_without_the_simulation():
    # the atomic file writes every output goes through must not load the physics
    code = ("import sys, synth.files; "
            "print(any(m in sys.modules for m in ('synth.model', 'synth.render', 'numba')))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout.strip()
    assert out == "False"
