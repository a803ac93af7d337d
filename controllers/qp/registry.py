"""QP back-ends by name (the ``mpc.qp_backend`` setting)."""

from __future__ import annotations

import numpy as np

from controllers.qp.base import OcpQp, QpBackend
from controllers.qp.condensed import CondensedDaqpBackend
from controllers.qp.osqp_backend import OsqpBackend

BACKEND_NAMES = ("hpipm", "osqp", "daqp")


def make_backend(
    name: str,
    template: OcpQp,
    a_pattern: np.ndarray | None = None,
    b_pattern: np.ndarray | None = None,
) -> QpBackend:
    """A back-end for QPs shaped like ``template``; patterns are the structural nonzeros of
    A and B (used by the sparse formulations)."""
    if name == "osqp":
        return OsqpBackend(template, a_pattern, b_pattern)
    if name == "daqp":
        return CondensedDaqpBackend(template)
    if name == "hpipm":
        from controllers.qp.hpipm import HpipmBackend  # loads libhpipm only when chosen

        return HpipmBackend(template)
    raise ValueError(f"unknown QP back-end {name!r}; choose one of {', '.join(BACKEND_NAMES)}")
