"""The front door: ``from trackers import Tracker`` and the rest, loaded on first use."""

import importlib
import subprocess
import sys

import pytest

import trackers


def test_every_exported_name_resolves_to_its_defining_module():
    for name, module in trackers._EXPORTS.items():
        assert getattr(trackers, name) is getattr(importlib.import_module(module), name), name
    assert set(dir(trackers)) == set(trackers.__all__)


def test_unknown_names_raise_attribute_error():
    with pytest.raises(AttributeError, match="no attribute 'Trakcer'"):
        trackers.Trakcer  # noqa: B018


def test_a_module_of_the_package_loads_without_the_landmark_models():
    code = ("import sys, trackers.polyline; "
            "print(any(m in sys.modules for m in ('trackers.anchored', 'trackers.landmarks', "
            "'cv2')))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout.strip()
    assert out == "False"
