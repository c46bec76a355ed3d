"""sweepedit: abstract 3D shapes into editable sweep-surface primitives (SweepNet)."""

__version__ = "0.1.0"
