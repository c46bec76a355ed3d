"""sweepedit: abstract 3D shapes into editable sweep-surface primitives (SweepNet).

    import sweepedit
    shape = sweepedit.load_shape("cow.obj")    # a path, trimesh, PyVista, points, voxels
    abstraction = sweepedit.fit(shape, primitives=8)
    print(sweepedit.evaluate(abstraction, shape))
    abstraction.save("cow.json")
    abstraction.export("cow.glb")             # .obj .ply .stl .glb .step .blend

docs/api.md has the whole interface. The names below load on first use (`sweepedit.api`),
so `import sweepedit` is instant and torch loads only when a fit starts.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

__version__ = "0.1.0"

_API = ("Abstraction", "Metrics", "evaluate", "example", "export", "fit", "fit_settings",
        "inside", "load", "load_shape")
_ELSEWHERE = {"Shape": "sweepedit.io.shapes", "SweepPrimitive": "sweepedit.geometry.model",
              "Normalization": "sweepedit.geometry.model",
              "SweepeditError": "sweepedit.errors", "FileFormatError": "sweepedit.errors"}
# Spelled out (not built from the two above) so that linters and IDEs read it.
__all__ = ["Abstraction", "FileFormatError", "Metrics", "Normalization", "Shape",
           "SweepPrimitive", "SweepeditError", "__version__", "evaluate", "example", "export",
           "fit", "fit_settings", "inside", "load", "load_shape"]

if TYPE_CHECKING:
    from sweepedit.api import (
        Abstraction,
        Metrics,
        evaluate,
        example,
        export,
        fit,
        fit_settings,
        inside,
        load,
        load_shape,
    )
    from sweepedit.errors import FileFormatError, SweepeditError
    from sweepedit.geometry.model import Normalization, SweepPrimitive
    from sweepedit.io.shapes import Shape


def __getattr__(name: str) -> Any:
    import importlib

    if name in _API:
        module = importlib.import_module("sweepedit.api")
    elif name in _ELSEWHERE:
        module = importlib.import_module(_ELSEWHERE[name])
    else:
        raise AttributeError(f"module 'sweepedit' has no attribute {name!r}")
    value = getattr(module, name)
    globals()[name] = value  # the next access is a plain lookup
    return value


def __dir__() -> list[str]:
    return sorted(__all__)
