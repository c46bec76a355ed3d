"""Primitives whose sections cross, shared by the STEP export tests."""

from __future__ import annotations

from sweepedit.geometry.model import SweepPrimitive

# Sweeps whose sections cross, which no loft through their sections builds: a tight bend
# with a wide profile (it reaches past the centre of curvature), a hairpin whose forward
# sections meet across the bend however far they are clamped, and a V whose axis comes
# back close to itself.
CROSSING = [
    SweepPrimitive([[-0.1, 0, 0], [0, 0.1, 0], [0.1, 0, 0]], a=0.2, b=0.05, degree=2.0,
                   name="elbow"),
    SweepPrimitive([[0.0, -0.08, 0.0], [0.0, 0.17, -0.01], [0.0, 0.09, 0.015]], a=0.08,
                   b=0.085, degree=2.1, scaling=(0.25, -0.08), name="hairpin"),
    SweepPrimitive([[-0.08, 0.23, -0.27], [0.02, 0.05, 0.33], [0.08, 0.23, -0.27]], a=0.03,
                   b=0.03, degree=2.1, scaling=(0.0, 0.13), name="vee"),
    # From a K = 8 fit of eight.stl: the loft of its forward sections (the profile clamped
    # short of the fold) passed the checker and the volume check, but intersected itself.
    SweepPrimitive([[0.0934, -0.0755, 0.0825], [0.0803, 0.0174, 0.2435],
                    [0.0180, 0.0367, 0.0129]], a=0.0542, b=0.0223, degree=1.715,
                   scaling=(0.2368, 0.0638), name="eight6"),
]
