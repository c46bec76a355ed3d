"""What the STEP modules share: OpenCascade's import, the export's errors, which paths
are STEP files, and the sewing tolerance that building and checking solids both use.

OpenCascade (the `cad` extra, package cadquery-ocp-novtk) is imported only when a STEP
file is made, so the rest of sweepedit works without it: the modules of this package
import OCP only inside their functions, and load_occ() turns its absence into
CadUnavailableError with the line that says how to install it.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from sweepedit.errors import SweepeditError

STEP_FORMATS = (".step", ".stp")
CAD_MISSING = "STEP export needs the optional 'cad' extra: pip install 'sweepedit[cad]'"
# Sewing tolerance, relative to the solid's size: neighbouring faces share their edge
# curves exactly, so this only absorbs rounding.
SEW_TOLERANCE = 1e-7


class CadUnavailableError(SweepeditError):
    """OpenCascade (the optional `cad` extra) is not installed."""

    def __init__(self) -> None:
        super().__init__(CAD_MISSING)


class StepExportError(SweepeditError):
    """A primitive or union that cannot be written as a correct solid."""


class ExportCancelledError(SweepeditError):
    """The user cancelled a STEP export; nothing was written."""

    def __init__(self) -> None:
        super().__init__("STEP export cancelled; nothing was written")


def is_step_path(path: str | Path) -> bool:
    """True when `path` names a STEP file (.step or .stp, any case)."""
    return Path(path).suffix.lower() in STEP_FORMATS


def load_occ() -> Any:
    """The OCP package, or CadUnavailableError with the line that says how to install it."""
    try:
        import OCP
        from OCP.Message import Message, Message_Gravity
    except ImportError:
        raise CadUnavailableError() from None
    # OpenCascade's translators print statistics to stdout; only failures are wanted.
    for printer in Message.DefaultMessenger_s().Printers():
        printer.SetTraceLevel(Message_Gravity.Message_Fail)
    return OCP
