"""Force fields and bilinear sampling (:mod:`trackers.sampling`)."""

import numpy as np
import pytest

from trackers.sampling import force_field, sample_bilinear


def test_force_points_downhill_and_sampling():
    x = np.arange(30, dtype=float)
    P = np.tile(-np.exp(-((x - 12.0) ** 2) / 8.0), (10, 1))
    F = force_field(P, p=2.0)
    assert F.shape == (10, 30, 2)
    assert F[5, 8, 0] > 0 and F[5, 16, 0] < 0
    assert np.allclose(F[..., 1], 0)
    v = sample_bilinear(F, [[8.5, 5.25]])
    np.testing.assert_allclose(v[0], 0.5 * (F[5, 8] + F[5, 9]), rtol=1e-6)
    np.testing.assert_allclose(sample_bilinear(P, [[3, 4]], origin=(1, 1)), [P[3, 2]])
    with pytest.raises(ValueError, match="outside"):
        sample_bilinear(P, [[30.5, 2]])
    with pytest.raises(ValueError, match="NaN"):
        sample_bilinear(P, [[np.nan, 2]])
    with pytest.raises(ValueError, match="NaN"):
        force_field(np.full((4, 4), np.nan))
