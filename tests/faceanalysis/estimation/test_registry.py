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
