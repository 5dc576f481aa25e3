"""The estimator registry: one name per estimator, one error for an unknown one."""

import numpy as np
import pytest

from faceanalysis.estimation.registry import ESTIMATORS, Observations, run_estimator


def test_registry_names_every_estimator():
    assert tuple(ESTIMATORS) == ("joint", "mesh", "model", "fused", "tw93", "flow")


def test_unknown_estimator_lists_the_valid_ones():
    obs = Observations(tracks=None, response=None, displacements=np.zeros((1, 1, 2)), neutral=0)
    with pytest.raises(ValueError, match="choose from joint, mesh, model, fused, tw93, flow"):
        run_estimator("magic", obs)


def test_estimate_prints_its_size_not_its_values():
    import pandas as pd

    from faceanalysis.estimation.registry import Estimate
    from tests.faceanalysis.estimation.test_estimators import _response

    response = _response(np.random.default_rng(0))
    values = pd.DataFrame(np.zeros((5000, 4)), columns=list(response.muscles))
    est = Estimate(values, response, np.zeros((5000, 4, 2)))
    assert repr(est) == "<Estimate: 4 controls on 5000 frames, from 4 points>"
