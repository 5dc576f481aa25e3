"""A small contraction time series for the resynthesis tests."""

import numpy as np
import pandas as pd

SMILE = ("zygomaticus_major_l", "zygomaticus_major_r")


def _drive(n=4):
    c = np.linspace(0.0, 0.8, n)
    return pd.DataFrame({SMILE[0]: c, SMILE[1]: c, "jaw_rotation": np.linspace(0, 0.1, n)})
