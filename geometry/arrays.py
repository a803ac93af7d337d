"""The one array type of the project: a float64 numpy array (shapes in the docstrings)."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]
