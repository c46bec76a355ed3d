"""Array shapes checked at public boundaries, as trimesh's `util.is_shape` does: a
function that takes (N, 3) points says so and refuses anything else with a ValueError,
instead of reshaping it silently.

A shape is written as people write it: "N, 3" (any N, then 3), "R, R, R" (three equal
lengths), "..., 3" (any leading axes, then 3), "T" (one axis of any length).
"""

from __future__ import annotations

from typing import Any

import numpy as np


def _axes(spec: str) -> list[str]:
    return [axis.strip() for axis in spec.split(",")]


def shape_matches(shape: tuple[int, ...], spec: str) -> bool:
    """Whether `shape` is of the form `spec`: numbers must match, a letter matches any
    length but the same letter the same length, a leading "..." any leading axes."""
    axes = _axes(spec)
    if axes[0] == "...":
        axes = axes[1:]
        if len(shape) < len(axes):
            return False
        shape = shape[len(shape) - len(axes):]
    elif len(shape) != len(axes):
        return False
    lengths: dict[str, int] = {}
    for length, axis in zip(shape, axes, strict=True):
        if axis.isdigit():
            if length != int(axis):
                return False
        elif lengths.setdefault(axis, length) != length:
            return False
    return True


def as_array(value: Any, spec: str, name: str, dtype: Any = np.float64,
             contiguous: bool = False) -> np.ndarray:
    """`value` as an array of `dtype` (C-contiguous if asked) whose shape is of the form
    `spec`; otherwise a ValueError such as "points must be an (N, 3) array, got (5,)"."""
    array = (np.ascontiguousarray(value, dtype=dtype) if contiguous
             else np.asarray(value, dtype=dtype))
    if not shape_matches(array.shape, spec):
        written = f"({spec},)" if len(_axes(spec)) == 1 else f"({spec})"
        raise ValueError(f"{name} must be an {written} array, got {array.shape}")
    return array
