"""The primitive and the abstraction as validated plain data (no Qt, no torch).

A `SweepPrimitive` is one sweep solid (docs/primitive.md); an `Abstraction` is an
ordered list of them plus the normalisation that maps them back to the original shape.
Both are plain dataclasses: the app's document wraps them and adds change notifications.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from sweepedit.errors import InvalidPrimitiveError
from sweepedit.geometry.sweep import fold_vectors, superellipse

# Parameter ranges of docs/primitive.md.
A_RANGE = (0.01, 0.5)
B_RANGE = (0.01, 0.5)
DEGREE_RANGE = (0.3, 5.0)
SCALING_RANGE = (-0.5, 0.5)
MIN_CONTROL_POINTS = 3
# Floats that went through text formats may sit a hair outside a range.
RANGE_TOLERANCE = 1e-6
# f(t) must stay above this on [0, 1] (a primitive that shrinks to a point is degenerate).
MIN_SCALE = 1e-3
MIN_AXIS_LENGTH = 1e-6

PALETTE = (
    "#e4572e", "#29335c", "#f3a712", "#669bbc", "#a8c686", "#8e5572", "#17bebb", "#d7263d",
    "#6a4c93", "#ffb400", "#2e86ab", "#c0392b", "#43aa8b", "#f08a4b", "#577590", "#b5838d",
)


def palette_color(index: int) -> str:
    """A distinct colour for the index-th primitive, as '#rrggbb'."""
    return PALETTE[index % len(PALETTE)]


def scaling_polynomial_min(scaling: Sequence[float], samples: int = 1025) -> float:
    """Minimum of f(t) = 1 + s1 t + s2 t^2 + ... over t in [0, 1].

    Exact for degree <= 2 (vertex and end points), dense sampling beyond.
    """
    s = [float(v) for v in scaling]
    t = np.linspace(0.0, 1.0, samples)
    candidates = [t]
    if len(s) == 2 and s[1] != 0.0:
        vertex = -s[0] / (2.0 * s[1])
        if 0.0 < vertex < 1.0:
            candidates.append(np.array([vertex]))
    t = np.concatenate(candidates)
    powers = np.stack([t ** (i + 1) for i in range(len(s))], axis=0) if s else np.zeros((0, t.size))
    f = 1.0 + np.asarray(s) @ powers if s else np.ones_like(t)
    return float(np.min(f))


# A primitive's geometry as a hashable value (SweepPrimitive.geometry_key).
GeometryKey = tuple


@dataclass
class SweepPrimitive:
    """One sweep solid: a superellipse profile swept along a clamped quadratic B-spline.

    control_points: (n, 3), n >= 3, in the normalised frame.
    a, b: half-axes of the profile along the frame's U and V; degree: the exponent d.
    scaling: s1..sk of f(t) = 1 + s1 t + ... + sk t^k (ascending powers, k >= 0).
    extras: keys found in a file that this version does not know; written back unchanged.
    """

    control_points: np.ndarray
    a: float = 0.05
    b: float = 0.05
    degree: float = 2.0
    scaling: tuple[float, ...] = (0.0, 0.0)
    name: str = ""
    color: str = "#e4572e"
    visible: bool = True
    locked: bool = False
    extras: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.control_points = np.array(self.control_points, dtype=np.float64, copy=True)
        self.a = float(self.a)
        self.b = float(self.b)
        self.degree = float(self.degree)
        self.scaling = tuple(float(s) for s in self.scaling)

    @property
    def n_control_points(self) -> int:
        return int(self.control_points.shape[0])

    @property
    def profile(self) -> np.ndarray:
        """(3,) array [a, b, d]."""
        return np.array([self.a, self.b, self.degree])

    @property
    def scaling_array(self) -> np.ndarray:
        """(1, k) the scaling coefficients as a batch of one, as sweep.py takes them."""
        return np.asarray(self.scaling, dtype=np.float64).reshape(1, -1)

    def batch_arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """This primitive as a batch of one for sweep.py's functions: control points
        (1, n, 3), profile (1, 3), scaling (1, k)."""
        return self.control_points[None], self.profile[None], self.scaling_array

    def geometry_key(self) -> GeometryKey:
        """What this primitive's solid depends on, as a hashable value (names, colours and
        flags do not count): equal keys mean the same solid."""
        return (self.control_points.tobytes(), self.control_points.shape, float(self.a),
                float(self.b), float(self.degree), tuple(float(s) for s in self.scaling))

    def copy(self) -> SweepPrimitive:
        return copy.deepcopy(self)

    def validate(self, index: int | None = None) -> None:
        """Raise InvalidPrimitiveError naming the field if any parameter is unusable."""
        cp = self.control_points
        if cp.ndim != 2 or cp.shape[1] != 3:
            raise InvalidPrimitiveError(
                f"control points must be an (n, 3) array, got shape {cp.shape}",
                primitive=index, field="control_points")
        if cp.shape[0] < MIN_CONTROL_POINTS:
            raise InvalidPrimitiveError(
                f"needs at least {MIN_CONTROL_POINTS} control points, got {cp.shape[0]}",
                primitive=index, field="control_points")
        if not np.all(np.isfinite(cp)):
            raise InvalidPrimitiveError("control points must be finite numbers",
                                        primitive=index, field="control_points")
        if float(np.sum(np.linalg.norm(np.diff(cp, axis=0), axis=1))) < MIN_AXIS_LENGTH:
            raise InvalidPrimitiveError("the axis has zero length (all control points coincide)",
                                        primitive=index, field="control_points")
        for name, value, (lo, hi) in (("a", self.a, A_RANGE), ("b", self.b, B_RANGE),
                                      ("degree", self.degree, DEGREE_RANGE)):
            _check_range(value, lo, hi, index, f"profile.{name}")
        for i, s in enumerate(self.scaling):
            _check_range(s, *SCALING_RANGE, index, f"scaling[{i}]")
        f_min = scaling_polynomial_min(self.scaling)
        if f_min <= MIN_SCALE:
            raise InvalidPrimitiveError(
                f"the scaling f(t) reaches {f_min:.4g} on [0, 1]; it must stay above 0",
                primitive=index, field="scaling")


def _check_range(value: float, lo: float, hi: float, index: int | None, name: str) -> None:
    if not math.isfinite(value):
        raise InvalidPrimitiveError(f"{value} is not a finite number", primitive=index, field=name)
    if not (lo - RANGE_TOLERANCE <= value <= hi + RANGE_TOLERANCE):
        raise InvalidPrimitiveError(f"{value:.6g} is outside [{lo}, {hi}]",
                                    primitive=index, field=name)


@dataclass
class Normalization:
    """Maps the normalised frame back to the original one: original = normalised*scale + center."""

    center: np.ndarray = field(default_factory=lambda: np.zeros(3))
    scale: float = 1.0

    def __post_init__(self) -> None:
        self.center = np.array(self.center, dtype=np.float64).reshape(3)
        self.scale = float(self.scale)
        if not (np.all(np.isfinite(self.center)) and math.isfinite(self.scale)
                and self.scale > 0.0):
            raise InvalidPrimitiveError("normalisation needs a finite centre and a scale > 0",
                                        field="normalization")

    @classmethod
    def from_bounds(cls, lower: np.ndarray, upper: np.ndarray) -> Normalization:
        """The normalisation of docs/parameter-format.md: box centre to the origin, longest
        side to 1."""
        lower = np.asarray(lower, dtype=np.float64)
        upper = np.asarray(upper, dtype=np.float64)
        extent = float(np.max(upper - lower))
        return cls(center=(lower + upper) / 2.0, scale=extent if extent > 0 else 1.0)

    def to_original(self, points: np.ndarray) -> np.ndarray:
        """(..., 3) normalised points -> original frame."""
        return np.asarray(points) * self.scale + self.center

    def to_normalized(self, points: np.ndarray) -> np.ndarray:
        """(..., 3) original points -> normalised frame."""
        return (np.asarray(points) - self.center) / self.scale


@dataclass
class Abstraction:
    """An ordered set of sweep primitives in the normalised frame of one shape."""

    primitives: list[SweepPrimitive] = field(default_factory=list)
    normalization: Normalization = field(default_factory=Normalization)
    source: dict[str, Any] | None = None
    fit: dict[str, Any] | None = None
    extras: dict[str, Any] = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.primitives)

    def copy(self) -> Abstraction:
        return copy.deepcopy(self)

    def validate(self) -> None:
        for i, p in enumerate(self.primitives):
            p.validate(i)

    def visible(self) -> list[SweepPrimitive]:
        return [p for p in self.primitives if p.visible]

    @classmethod
    def from_primitives(cls, primitives: Iterable[SweepPrimitive], **kwargs: Any) -> Abstraction:
        return cls(primitives=list(primitives), **kwargs)


def primitive_fold_vectors(primitive: SweepPrimitive, t: np.ndarray) -> np.ndarray:
    """q(t) of sweep.fold_vectors for one primitive, so that a profile point o moves along
    the axis at the rate J(t, o) = 1 - o . q(t): t (M,) -> (M, 2)."""
    return fold_vectors(primitive.control_points[None], primitive.scaling_array, t)[0]


def folds_onto_itself(primitive: SweepPrimitive, samples: int = 256) -> bool:
    """True when the profile reaches past the axis' centre of curvature somewhere: some
    profile point o has f (o . κN) >= 1, so the sweep runs backwards there and the swept
    surface self-intersects on the inner side of the bend (the solid is still well
    defined, but the display tube is not its boundary there; solid.py meshes it)."""
    q = primitive_fold_vectors(primitive, np.linspace(0.0, 1.0, samples))
    x, y = superellipse(np.linspace(0.0, 2.0 * np.pi, 64, endpoint=False), primitive.profile[None])
    return bool(np.any(q @ np.stack([x[0], y[0]]) >= 1.0))
