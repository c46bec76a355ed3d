"""Writing solids as an AP214 STEP file with names and colours, and reading it back:
the bytes of a file whose solids read back as checked (their volumes, and validity or
crossing), with STEP_DECIMALS decimals where that reads back so, else OpenCascade's own
13 digits; one solid as it reads back from its STEP text (as_written); read_step."""

from __future__ import annotations

import tempfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

from sweepedit.errors import SweepeditError
from sweepedit.io.step.checks import crosses_itself, is_valid, solid_volume
from sweepedit.io.step.occ import StepExportError, load_occ

# A solid read back from the file written must have the volume checked in memory this
# closely (relative): what it catches is gross (a solid inside out, -100 %; a face
# rebuilt wrong, -1.8 %, when the edges' curves on the faces were left out of the file),
# while a union's re-approximated edge curves move the re-read volume by up to ~1e-6,
# and two integrations at VOLUME_PRECISION may differ by up to ~2e-4.
READ_BACK_TOLERANCE = 1e-3
# Decimals of the coordinates, knots and parameters written (|x| in [0.1, 1e7]; smaller
# ones get 9 significant digits): within 5e-9, 20 times under OpenCascade's confusion
# distance (1e-7). OpenCascade's writer prints 13 significant digits; 8 decimals make the
# file 12-16 % smaller. Where a file so written does not read back as checked (knots
# closer than that would merge), it is written again with OpenCascade's 13 digits.
STEP_DECIMALS = 8
STEP_DECIMALS_RANGE = (0.1, 1e7)

# What a solid read back from its file is checked for besides its volume (_read_back_checked).
ReadBackCheck = Literal["validity", "crossing"]


def _color(hex_color: str) -> Any:
    from OCP.Quantity import Quantity_Color, Quantity_TOC_sRGB

    rgb = [int(hex_color[i:i + 2], 16) / 255.0 for i in (1, 3, 5)]
    return Quantity_Color(*rgb, Quantity_TOC_sRGB)


def step_bytes(parts: Sequence[tuple[Any, str, str]], path: Path,
                checks: Sequence[ReadBackCheck], budget: int | None = None,
                volumes: Sequence[float] | None = None) -> bytes:
    """Shapes with names and colours [(shape, name, '#rrggbb')] as the bytes of an AP214
    STEP file that reads back as checked (_read_back_checked), with STEP_DECIMALS
    decimals, or with OpenCascade's own 13 digits where that file reads back with other
    solids or volumes, or solids that cross themselves (the rounding could be why; an
    invalid solid of the right volume reads back invalid at 13 digits too, and is not
    written again). A file over `budget`
    bytes is written without the edges' curves on their faces where it reads back as
    checked that way (_checked_bytes). `checks`: what each part is checked for on reading
    back; `volumes`: the volume each must read back with, by default its own. `path` is
    the file meant, for messages."""
    parts = list(parts)
    checks = list(checks)
    expected = [solid_volume(shape) for shape, _, _ in parts] if volumes is None \
        else list(volumes)
    if not len(checks) == len(expected) == len(parts):
        raise ValueError(f"{len(checks)} read-back checks and {len(expected)} volumes "
                         f"for {len(parts)} solids")
    with tempfile.TemporaryDirectory(prefix="sweepedit-step-") as folder:
        tmp = Path(folder) / "export.step"
        if budget is not None:
            # Writing is cheap (0.2 s for a union of 8), reading back and checking is not:
            # the size is looked at first, and only one file is read back where it can.
            _write_step(parts, tmp, path, STEP_DECIMALS)
            if tmp.stat().st_size <= budget:  # read that file back, not another copy
                return _checked_bytes(parts, tmp, path, checks, expected,
                                      face_curves=True, written=True)
            try:
                return _checked_bytes(parts, tmp, path, checks, expected,
                                      face_curves=False)
            except StepExportError:
                pass  # read back otherwise than checked: the file with the curves
        return _checked_bytes(parts, tmp, path, checks, expected, face_curves=True)


def _checked_bytes(parts: list[tuple[Any, str, str]], tmp: Path, path: Path,
                   checks: list[ReadBackCheck], expected: list[float], face_curves: bool,
                   written: bool = False) -> bytes:
    """_read_back_checked with STEP_DECIMALS decimals, else with all digits (see
    step_bytes). `written`: tmp already holds `parts` written with STEP_DECIMALS
    decimals and these face_curves."""
    try:
        return _read_back_checked(parts, tmp, path, STEP_DECIMALS, checks, expected,
                                  face_curves, written)
    except _InvalidOnReadingError:
        raise  # not the rounding: the same at 13 digits (bone.json's unions)
    except StepExportError:
        return _read_back_checked(parts, tmp, path, None, checks, expected, face_curves)


class _InvalidOnReadingError(StepExportError):
    """A solid read back from its file with the volume checked, but invalid."""


def _read_back_checked(parts: list[tuple[Any, str, str]], tmp: Path, path: Path,
                       decimals: int | None, checks: list[ReadBackCheck],
                       expected: list[float], face_curves: bool = True,
                       written: bool = False) -> bytes:
    """The bytes of `parts` written as STEP (at tmp, by _write_step, unless `written`
    says tmp holds them so already), read back and each solid's volume compared with
    `expected` (the one checked in memory), and each solid whose entry of `checks` says "validity"
    checked by OpenCascade's checker, "crossing" by its self-interference check
    (crosses_itself: a solid that passes it in memory can cross itself within
    OpenCascade's tolerance once its numbers are rounded; 2 of 327 did at 8 decimals,
    BENCHMARKS.md, STEP export). OpenCascade's writer turns a few sewn solids inside out (the
    same volume, negated, on reading; seen on 1 of 378 primitives): such a solid is
    written reversed instead (in `parts`); anything else that differs is an error, not a
    file."""
    from OCP.TopoDS import TopoDS

    for attempt in range(2):
        if attempt or not written:
            _write_step(parts, tmp, path, decimals, face_curves)
        read = read_step(tmp)
        if len(read) != len(parts):
            raise StepExportError(f"{path}: {len(read)} solids read back from the "
                                  f"STEP file written, not {len(parts)}; not written")
        volumes = [solid_volume(r.shape) for r in read]
        flipped = [i for i, (v, e) in enumerate(zip(volumes, expected, strict=True))
                   if abs(v + e) <= READ_BACK_TOLERANCE * abs(e)]
        wrong = [parts[i][1] for i, (v, e) in enumerate(zip(volumes, expected, strict=True))
                 if i not in flipped and not abs(v - e) <= READ_BACK_TOLERANCE * abs(e)]
        if wrong:
            raise StepExportError(f"{path}: {', '.join(wrong)} read back from the STEP "
                                  "file with another volume than was checked; not written")
        invalid = [parts[i][1] for i, (r, check) in enumerate(zip(read, checks, strict=True))
                   if check == "validity" and not is_valid(r.shape, parallel=True)]
        if invalid:
            raise _InvalidOnReadingError(f"{path}: {', '.join(invalid)} read back from "
                                         "the STEP file as an invalid solid; not written")
        crossing = [parts[i][1] for i, (r, check) in enumerate(zip(read, checks, strict=True))
                    if check == "crossing" and crosses_itself(r.shape)]
        if crossing:
            raise StepExportError(f"{path}: {', '.join(crossing)} read back from the STEP "
                                  "file as a solid that crosses itself; not written. "
                                  "Export it as a mesh, or hide it and export the others")
        if not flipped:
            return tmp.read_bytes()
        for i in flipped:
            shape, name, color = parts[i]
            parts[i] = (TopoDS.Solid(shape.Reversed()), name, color)
    raise StepExportError(f"{path}: a solid reads back inside out from the STEP file "
                          "however it is written; not written")


def _write_step(parts: Sequence[tuple[Any, str, str]], tmp: Path, path: Path,
                decimals: int | None = None, face_curves: bool = True) -> None:
    """Write [(shape, name, '#rrggbb')] as an AP214 STEP file at tmp (not atomic), its
    real numbers with `decimals` decimals (STEP_DECIMALS_RANGE), or as OpenCascade writes
    them (None); without `face_curves`, the edges' curves on their faces (pcurves) are
    left out, and a reader computes them from the edges' 3D curves and the faces."""
    from OCP.IFSelect import IFSelect_RetDone
    from OCP.Interface import Interface_Static
    from OCP.StepAP214 import StepAP214_Protocol
    from OCP.STEPCAFControl import STEPCAFControl_Writer
    from OCP.STEPControl import STEPControl_AsIs
    from OCP.StepData import StepData_StepWriter
    from OCP.TCollection import TCollection_ExtendedString
    from OCP.TDataStd import TDataStd_Name
    from OCP.TDocStd import TDocStd_Document
    from OCP.XCAFDoc import XCAFDoc_ColorSurf, XCAFDoc_DocumentTool

    doc = TDocStd_Document(TCollection_ExtendedString("XmlXCAF"))
    shapes = XCAFDoc_DocumentTool.ShapeTool_s(doc.Main())
    colors = XCAFDoc_DocumentTool.ColorTool_s(doc.Main())
    for shape, name, color in parts:
        label = shapes.AddShape(shape, False)
        TDataStd_Name.Set_s(label, TCollection_ExtendedString(name))
        colors.SetColor(label, _color(color), XCAFDoc_ColorSurf)
    writer = STEPCAFControl_Writer()
    writer.SetNameMode(True)
    writer.SetColorMode(True)
    # A process-wide setting that the translation reads: set for this file, then reset.
    Interface_Static.SetIVal_s("write.surfacecurve.mode", int(face_curves))
    try:
        translated = writer.Transfer(doc, STEPControl_AsIs)
    finally:
        Interface_Static.SetIVal_s("write.surfacecurve.mode", 1)
    if not translated:
        raise StepExportError(f"{path}: OpenCascade could not translate the solids to STEP")
    if decimals is None:
        if writer.Write(str(tmp)) != IFSelect_RetDone or not tmp.is_file():
            raise StepExportError(f"{path}: OpenCascade could not write the STEP file")
        return
    # What STEPControl_Writer.Write does (StepSelect_WorkLibrary), with another format
    # for the reals, which that writer fixes at 12 digits after the point.
    lines = StepData_StepWriter(writer.ChangeWriter().Model())
    lines.FloatWriter().SetDefaults(decimals)
    lines.FloatWriter().SetFormatForRange(f"%.{decimals}f", *STEP_DECIMALS_RANGE)
    lines.SendModel(StepAP214_Protocol())
    text = "\n".join(lines.Line(i).ToCString() for i in range(1, lines.NbLines() + 1))
    tmp.write_text(text + "\n", encoding="utf-8")


def as_written(solid: Any, what: str) -> Any:
    """The solid as read back from the STEP text export_step writes of it (with
    STEP_DECIMALS decimals): a folding solid is checked for crossing itself once, as it
    will be read, where checking it in memory and again read back from the file cost
    0.5 s of the 1.1 s median of a folding primitive (BENCHMARKS.md, STEP export). The
    rounding can tip a contact within OpenCascade's tolerance into a crossing (bone.json's
    6th), and written again the read-back solid has the same surfaces and edges to the
    last digit (only its caps' planes and their edges' curves on them move, by 1e-10).
    Turned right way out where it reads back inside out (see _read_back_checked)."""
    from OCP.TopoDS import TopoDS

    with tempfile.TemporaryDirectory(prefix="sweepedit-step-") as folder:
        tmp = Path(folder) / "solid.step"
        _write_step([(solid, "solid", "#000000")], tmp, tmp, STEP_DECIMALS)
        read = read_step(tmp)
    expected = solid_volume(solid)
    volume = solid_volume(read[0].shape) if len(read) == 1 else 0.0
    if not abs(abs(volume) - expected) <= READ_BACK_TOLERANCE * abs(expected):
        raise StepExportError(f"{what}: its solid reads back from STEP text with another "
                              "volume; not written")
    shape = read[0].shape if volume > 0.0 else read[0].shape.Reversed()
    return TopoDS.Solid(shape)


# --------------------------------------------------------------------------- reading


@dataclass
class StepSolid:
    """A solid read back from a STEP file: its OpenCascade shape, name and colour."""

    shape: Any
    name: str
    color: str | None


def read_step(path: str | Path) -> list[StepSolid]:
    """The top-level shapes of a STEP file with their names and colours (OpenCascade's
    XCAF reader); used to check what export_step wrote."""
    load_occ()
    from OCP.collections import Sequence_TDF_Label
    from OCP.IFSelect import IFSelect_RetDone
    from OCP.Quantity import Quantity_Color, Quantity_TOC_sRGB
    from OCP.STEPCAFControl import STEPCAFControl_Reader
    from OCP.TCollection import TCollection_ExtendedString
    from OCP.TDataStd import TDataStd_Name
    from OCP.TDocStd import TDocStd_Document
    from OCP.XCAFDoc import XCAFDoc_ColorSurf, XCAFDoc_DocumentTool

    reader = STEPCAFControl_Reader()
    reader.SetNameMode(True)
    reader.SetColorMode(True)
    if reader.ReadFile(str(path)) != IFSelect_RetDone:
        raise SweepeditError(f"{path}: OpenCascade cannot read this STEP file")
    doc = TDocStd_Document(TCollection_ExtendedString("XmlXCAF"))
    reader.Transfer(doc)
    shapes = XCAFDoc_DocumentTool.ShapeTool_s(doc.Main())
    colors = XCAFDoc_DocumentTool.ColorTool_s(doc.Main())
    labels = Sequence_TDF_Label()
    shapes.GetFreeShapes(labels)
    out = []
    for i in range(1, labels.Length() + 1):
        label = labels.Value(i)
        name_attr = TDataStd_Name()
        name = (name_attr.Get().ToExtString()
                if label.FindAttribute(TDataStd_Name.GetID_s(), name_attr) else "")
        color = Quantity_Color()
        hex_color = None
        if colors.GetColor(shapes.GetShape_s(label), XCAFDoc_ColorSurf, color):
            r, g, b = color.Values(Quantity_TOC_sRGB)
            hex_color = "#" + "".join(f"{round(v * 255):02x}" for v in (r, g, b))
        out.append(StepSolid(shapes.GetShape_s(label), name, hex_color))
    return out
