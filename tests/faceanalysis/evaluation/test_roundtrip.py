"""The round trip: render, analyse, resynthesise."""

from __future__ import annotations

import pytest


@pytest.mark.slow
def test_round_trip_small_case():
    from faceanalysis.evaluation.roundtrip import round_trip

    # the standard suite's sequence length (faceanalysis.evaluation.suite.SuiteConfig.frames)
    table = round_trip([(101, "surprise")], frames=30)
    assert table.loc[0, "frames"] >= 28
    assert table.loc[0, "fiducial_error_px"] < 1.5
