"""Hypothesis strategies shared by the geometry tests."""

from __future__ import annotations

import numpy as np
from hypothesis import strategies as st

from sweepedit.errors import InvalidPrimitiveError
from sweepedit.geometry.model import SweepPrimitive


def is_valid(p: SweepPrimitive) -> bool:
    """Valid, and no two consecutive control points closer than a hair (an axis with a
    kink-free but degenerate start)."""
    try:
        p.validate()
    except InvalidPrimitiveError:
        return False
    return bool(np.min(np.linalg.norm(np.diff(p.control_points, axis=0), axis=1)) > 1e-3)


# Random valid primitives over the whole ranges of docs/primitive.md, tight bends included:
# 3 to 5 control points in [-0.5, 0.5]^3.
coord = st.floats(-0.5, 0.5, allow_nan=False)
primitives = st.builds(
    lambda cps, a, b, d, s1, s2: SweepPrimitive(np.array(cps).reshape(-1, 3), a=a, b=b, degree=d,
                                                scaling=(s1, s2)),
    st.lists(coord, min_size=9, max_size=15).filter(lambda v: len(v) % 3 == 0),
    st.floats(0.01, 0.5), st.floats(0.01, 0.5), st.floats(0.3, 5.0),
    st.floats(-0.5, 0.5), st.floats(-0.5, 0.5),
).filter(is_valid)
