"""Fit a shape, edit the result in code, and export it.

    python examples/edit_and_export.py SHAPE OUT.glb [--primitives K]

Fits SHAPE, makes every primitive's profile 20% wider than fitted (a thicker version of
the abstraction, say for a 3D print), checks the edit, reports what it did to the
metrics, and exports the union (any format `sweepedit export` writes: .glb .obj .ply
.stl .step .blend, or .json for the parameters).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import sweepedit


def thicken(abstraction: sweepedit.Abstraction, factor: float) -> None:
    """Scale every primitive's profile half-axes by `factor`, in place."""
    for primitive in abstraction.primitives:
        primitive.a *= factor
        primitive.b *= factor
    abstraction.validate()  # a half-axis past its range is an error naming the primitive


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("shape", type=Path)
    parser.add_argument("output", type=Path)
    parser.add_argument("--primitives", type=int, default=8)
    parser.add_argument("--factor", type=float, default=1.2)
    args = parser.parse_args()
    try:
        shape = sweepedit.load_shape(args.shape)
        abstraction = sweepedit.fit(shape, args.primitives)
        before = sweepedit.evaluate(abstraction, shape)
        volume = abstraction.to_trimesh().volume
        thicken(abstraction, args.factor)
        after = sweepedit.evaluate(abstraction, shape)
        written = abstraction.export(args.output, original_frame=True)
    except sweepedit.SweepeditError as exc:
        print(f"edit_and_export: {exc}", file=sys.stderr)
        return 2
    print(f"fitted:    {before}")
    print(f"thickened: {after}")
    print(f"volume x{abstraction.to_trimesh().volume / volume:.2f} -> "
          f"{', '.join(map(str, written))}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
