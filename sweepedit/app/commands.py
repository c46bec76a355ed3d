"""Undoable edits of a Document and a Qt-free undo stack.

Every edit the user makes is a Command pushed on the CommandStack. Commands keep exact
copies of what they replace, so undo restores bit-identical arrays. Consecutive commands
with the same merge key (a control-point drag, a slider move) merge into one undo step
until the stack is told the gesture ended (`close_merge`, on mouse or slider release).
"""

from __future__ import annotations

import copy
import math
from collections.abc import Hashable, Sequence
from typing import Any

import numpy as np

from sweepedit.app.document import (
    EDITABLE_FIELDS,
    GEOMETRY_FIELDS,
    Document,
    Signal,
    ensure_distinct_colors,
)
from sweepedit.errors import InvalidPrimitiveError
from sweepedit.geometry import axis_edit
from sweepedit.geometry.model import SweepPrimitive, palette_color


class Command:
    """Base of undoable edits. `redo` is also the first execution.

    check(doc) raises (e.g. InvalidPrimitiveError) before anything changes when the edit
    would make the document invalid; the stack then refuses the command.
    """

    text = "Edit"
    merge_key: Hashable | None = None

    def check(self, doc: Document) -> None:
        """Raise if the edit cannot be applied; must not change the document."""

    def redo(self, doc: Document) -> None:
        raise NotImplementedError

    def undo(self, doc: Document) -> None:
        raise NotImplementedError

    def merge(self, newer: Command) -> None:
        """Absorb a newer command with the same merge key that has already been executed."""
        raise NotImplementedError


class SetControlPoints(Command):
    """Replace one primitive's control points (moving a point, transforming the primitive),
    optionally with new profile half-axes a, b (`profile`, when the whole primitive is
    scaled): one undo step either way."""

    def __init__(self, index: int, control_points: np.ndarray, text: str = "Move control points",
                 merge_key: Hashable | None = None,
                 profile: dict[str, float] | None = None) -> None:
        self.index = index
        self.new = np.array(control_points, dtype=np.float64, copy=True)
        self.old: np.ndarray | None = None
        self.new_profile = {k: float(v) for k, v in (profile or {}).items()}
        if set(self.new_profile) - {"a", "b"}:
            raise KeyError(f"not a profile half-axis: {sorted(set(self.new_profile) - {'a', 'b'})}")
        self.old_profile: dict[str, float] = {}
        self.text = text
        self.merge_key = merge_key

    def check(self, doc: Document) -> None:
        candidate = doc.primitive(self.index).copy()
        candidate.control_points = self.new
        for name, value in self.new_profile.items():
            setattr(candidate, name, value)
        candidate.validate(self.index)

    def redo(self, doc: Document) -> None:
        if self.old is None:
            prim = doc.primitive(self.index)
            self.old = prim.control_points.copy()
            self.old_profile = {name: getattr(prim, name) for name in self.new_profile}
        doc.set_control_points(self.index, self.new, self.new_profile)

    def undo(self, doc: Document) -> None:
        assert self.old is not None
        doc.set_control_points(self.index, self.old, self.old_profile)

    def merge(self, newer: Command) -> None:
        assert isinstance(newer, SetControlPoints)
        self.new = newer.new
        for name, value in newer.new_profile.items():
            self.old_profile.setdefault(name, newer.old_profile[name])
            self.new_profile[name] = value


class SetFields(Command):
    """Set profile, scaling or display fields of one primitive (a, b, degree, scaling,
    name, color, visible, locked)."""

    def __init__(self, index: int, values: dict[str, Any], text: str | None = None,
                 merge_key: Hashable | None = None) -> None:
        unknown = set(values) - EDITABLE_FIELDS
        if unknown:
            raise KeyError(f"not editable: {sorted(unknown)}")
        self.index = index
        self.new = copy.deepcopy(dict(values))
        self.old: dict[str, Any] | None = None
        self.text = text or "Set " + ", ".join(values)
        self.merge_key = merge_key

    def check(self, doc: Document) -> None:
        candidate = doc.primitive(self.index).copy()
        for name, value in self.new.items():
            setattr(candidate, name, value)
        candidate.__post_init__()  # normalise types as the dataclass does
        candidate.validate(self.index)

    def redo(self, doc: Document) -> None:
        prim = doc.primitive(self.index)
        if self.old is None:
            self.old = {name: copy.deepcopy(getattr(prim, name)) for name in self.new}
        doc.set_fields(self.index, self.new)

    def undo(self, doc: Document) -> None:
        assert self.old is not None
        doc.set_fields(self.index, self.old)

    def merge(self, newer: Command) -> None:
        assert isinstance(newer, SetFields) and newer.old is not None and self.old is not None
        for name, value in newer.new.items():
            self.old.setdefault(name, newer.old[name])
            self.new[name] = value


class AddPrimitive(Command):
    """Insert a primitive (new or duplicated) and select it."""

    def __init__(self, primitive: SweepPrimitive, index: int | None = None,
                 text: str = "Add primitive") -> None:
        self.primitive = primitive.copy()
        self.index = index
        self.text = text
        self.previous_selection: int | None = None

    def check(self, doc: Document) -> None:
        self.primitive.validate()

    def redo(self, doc: Document) -> None:
        if self.index is None:
            self.index = len(doc)
        self.previous_selection = doc.selection
        doc.insert_primitive(self.index, self.primitive.copy())
        doc.select(self.index)

    def undo(self, doc: Document) -> None:
        assert self.index is not None
        doc.remove_primitive(self.index)
        doc.select(self.previous_selection)


class DeletePrimitive(Command):
    """Remove a primitive; undo puts the very same values back at the same index."""

    def __init__(self, index: int, text: str = "Delete primitive") -> None:
        self.index = index
        self.text = text
        self.removed: SweepPrimitive | None = None
        self.previous_selection: int | None = None

    def redo(self, doc: Document) -> None:
        self.previous_selection = doc.selection
        self.removed = doc.remove_primitive(self.index)
        if len(doc):
            doc.select(min(self.index, len(doc) - 1))

    def undo(self, doc: Document) -> None:
        assert self.removed is not None
        doc.insert_primitive(self.index, self.removed.copy())
        doc.select(self.previous_selection)


class ReplacePrimitives(Command):
    """Replace all primitives at once (applying a fit result)."""

    def __init__(self, primitives: Sequence[SweepPrimitive], fit: dict[str, Any] | None = None,
                 text: str = "Apply fit") -> None:
        self.new = [p.copy() for p in primitives]
        self.new_fit = copy.deepcopy(fit)
        self.old: list[SweepPrimitive] | None = None
        self.old_fit: dict[str, Any] | None = None
        self.text = text

    def check(self, doc: Document) -> None:
        for i, p in enumerate(self.new):
            p.validate(i)

    def redo(self, doc: Document) -> None:
        if self.old is None:
            self.old = [p.copy() for p in doc.primitives]
            self.old_fit = copy.deepcopy(doc.abstraction.fit)
        doc.replace_primitives([p.copy() for p in self.new], copy.deepcopy(self.new_fit))

    def undo(self, doc: Document) -> None:
        assert self.old is not None
        doc.replace_primitives([p.copy() for p in self.old], copy.deepcopy(self.old_fit))


class SetGeometry(Command):
    """Replace one primitive's axis (any number of control points) and geometry fields
    (a, b, degree, scaling) at once: inserting or deleting a control point."""

    def __init__(self, index: int, control_points: np.ndarray, values: dict[str, Any],
                 text: str = "Edit axis", merge_key: Hashable | None = None) -> None:
        unknown = set(values) - GEOMETRY_FIELDS
        if unknown:
            raise KeyError(f"not geometry fields: {sorted(unknown)}")
        self.index = index
        self.new_points = np.array(control_points, dtype=np.float64, copy=True)
        self.new = copy.deepcopy(dict(values))
        self.old_points: np.ndarray | None = None
        self.old: dict[str, Any] = {}
        self.text = text
        self.merge_key = merge_key

    def check(self, doc: Document) -> None:
        candidate = doc.primitive(self.index).copy()
        candidate.control_points = self.new_points
        for name, value in self.new.items():
            setattr(candidate, name, value)
        candidate.__post_init__()
        candidate.validate(self.index)

    def redo(self, doc: Document) -> None:
        if self.old_points is None:
            prim = doc.primitive(self.index)
            self.old_points = prim.control_points.copy()
            self.old = {name: copy.deepcopy(getattr(prim, name)) for name in self.new}
        doc.set_geometry(self.index, self.new_points, self.new)

    def undo(self, doc: Document) -> None:
        assert self.old_points is not None
        doc.set_geometry(self.index, self.old_points, self.old)

    def merge(self, newer: Command) -> None:
        assert isinstance(newer, SetGeometry)
        self.new_points = newer.new_points
        for name, value in newer.new.items():
            self.old.setdefault(name, newer.old[name])
            self.new[name] = value


class MacroCommand(Command):
    """Several commands as one undo step (an edit of a multi-selection, a symmetric
    edit). The parts must not depend on each other's effects when checked (they edit
    different primitives); they run in order and undo in reverse."""

    def __init__(self, parts: Sequence[Command], text: str = "Edit",
                 merge_key: Hashable | None = None) -> None:
        if not parts:
            raise ValueError("a macro needs at least one command")
        self.parts = list(parts)
        self.text = text
        self.merge_key = merge_key

    def check(self, doc: Document) -> None:
        for part in self.parts:
            part.check(doc)

    def redo(self, doc: Document) -> None:
        for part in self.parts:
            part.redo(doc)

    def undo(self, doc: Document) -> None:
        for part in reversed(self.parts):
            part.undo(doc)

    def merge(self, newer: Command) -> None:
        assert isinstance(newer, MacroCommand) and len(newer.parts) == len(self.parts)
        for mine, theirs in zip(self.parts, newer.parts, strict=True):
            mine.merge(theirs)


class MirrorPrimitives(Command):
    """Add mirrored copies of primitives (through a coordinate plane of the shape's
    frame) after the last primitive, and select the copies."""

    def __init__(self, copies: Sequence[SweepPrimitive], text: str = "Mirror") -> None:
        self.copies = [p.copy() for p in copies]
        self.text = text
        self.start: int | None = None
        self.previous: list[int] = []

    def check(self, doc: Document) -> None:
        for p in self.copies:
            p.validate()

    def redo(self, doc: Document) -> None:
        self.previous = list(doc.selected_indices)
        self.start = len(doc)
        for p in self.copies:
            doc.insert_primitive(len(doc), p.copy())
        doc.set_selection(range(self.start, len(doc)))

    def undo(self, doc: Document) -> None:
        assert self.start is not None
        for i in reversed(range(self.start, self.start + len(self.copies))):
            doc.remove_primitive(i)
        doc.set_selection(self.previous)


class DeletePrimitives(Command):
    """Remove several primitives in one step; undo puts the very same values back at the
    same indices and restores the selection."""

    def __init__(self, indices: Sequence[int], text: str = "Delete primitives") -> None:
        self.indices = sorted(set(int(i) for i in indices))
        self.text = text
        self.removed: list[SweepPrimitive] = []
        self.previous: list[int] = []

    def redo(self, doc: Document) -> None:
        self.previous = list(doc.selected_indices)
        self.removed = [doc.remove_primitive(i) for i in reversed(self.indices)][::-1]
        if len(doc):
            doc.select(min(self.indices[0], len(doc) - 1))

    def undo(self, doc: Document) -> None:
        for i, prim in zip(self.indices, self.removed, strict=True):
            doc.insert_primitive(i, prim.copy())
        doc.set_selection(self.previous)


class CommandStack:
    """Undo/redo history of one Document, with merging and a clean (saved) mark.

    Signal `changed()` fires after every push, undo, redo, clear and set_clean.
    """

    def __init__(self, doc: Document, limit: int = 500) -> None:
        self.doc = doc
        self.limit = limit
        self._undo: list[Command] = []
        self._redo: list[Command] = []
        self._clean: int | None = 0  # len(_undo) when saved; None: unreachable
        self._merge_open = False
        # Symmetric editing: an edit of one of a mirrored pair is made to both (one step).
        self.symmetric = False
        self.changed = Signal()

    # -- state ----------------------------------------------------------------------------
    @property
    def can_undo(self) -> bool:
        return bool(self._undo)

    @property
    def can_redo(self) -> bool:
        return bool(self._redo)

    @property
    def undo_text(self) -> str:
        return self._undo[-1].text if self._undo else ""

    @property
    def redo_text(self) -> str:
        return self._redo[-1].text if self._redo else ""

    @property
    def is_clean(self) -> bool:
        return self._clean == len(self._undo)

    def __len__(self) -> int:
        return len(self._undo)

    # -- operations -----------------------------------------------------------------------
    def push(self, command: Command) -> None:
        """Execute `command` and record it (merged into the previous one when they share
        a merge key and the gesture is still going on). Raises what check() raises.
        With `symmetric` on, the mirror partners of the primitives it edits get the
        mirrored edit in the same step (with_mirror_partners)."""
        if self.symmetric:
            command = with_mirror_partners(self.doc, command)
        command.check(self.doc)
        top = self._undo[-1] if self._undo else None
        merging = (self._merge_open and top is not None and command.merge_key is not None
                   and command.merge_key == top.merge_key and not self._redo)
        command.redo(self.doc)
        if merging:
            assert top is not None
            top.merge(command)
            if self._clean == len(self._undo):
                self._clean = None  # the saved state was inside the merged step
        else:
            if self._clean is not None and self._clean > len(self._undo):
                self._clean = None  # the saved state was on the discarded redo branch
            self._redo.clear()
            self._undo.append(command)
            if len(self._undo) > self.limit:
                del self._undo[0]
                self._clean = None if self._clean in (None, 0) else self._clean - 1
        self._merge_open = command.merge_key is not None
        self._changed()

    def close_merge(self) -> None:
        """End the current gesture: the next command starts a new undo step."""
        self._merge_open = False

    def revert_open(self) -> bool:
        """Cancel the gesture going on (Esc during a drag): undo its merged step, which
        restores the exact old values, and forget it (it cannot be redone). False when
        no gesture is open."""
        if not self._merge_open or not self._undo:
            self._merge_open = False
            return False
        self._merge_open = False
        self._undo.pop().undo(self.doc)
        if self._clean is not None and self._clean > len(self._undo):
            self._clean = None
        self._changed()
        return True

    def undo(self) -> None:
        self._merge_open = False
        if not self._undo:
            return
        command = self._undo.pop()
        command.undo(self.doc)
        self._redo.append(command)
        self._changed()

    def redo(self) -> None:
        self._merge_open = False
        if not self._redo:
            return
        command = self._redo.pop()
        command.redo(self.doc)
        self._undo.append(command)
        self._changed()

    def clear(self) -> None:
        """Forget the history (after opening a file); the document counts as saved."""
        self._undo.clear()
        self._redo.clear()
        self._clean = 0
        self._merge_open = False
        self._changed()

    def mark_modified(self) -> None:
        """The document changed outside the history (a new target shape kept with its
        primitives, recovered edits): unsaved until the next save, whatever is undone."""
        self._clean = None
        self._merge_open = False
        self._changed()

    def set_clean(self) -> None:
        """Mark the current state as saved."""
        self._clean = len(self._undo)
        self._merge_open = False
        self._changed()

    def _changed(self) -> None:
        self.doc.set_dirty(not self.is_clean)
        self.changed.emit()


# -- command factories (what the views call) ----------------------------------------------

def move_control_point(doc: Document, index: int, cp_index: int,
                       position: Sequence[float]) -> SetControlPoints:
    """Move control point `cp_index` of primitive `index` to `position` (3,); consecutive
    moves of the same point merge into one undo step."""
    points = doc.primitive(index).control_points.copy()
    points[cp_index] = np.asarray(position, dtype=np.float64).reshape(3)
    return SetControlPoints(index, points, text="Move control point",
                            merge_key=("control_point", index, cp_index))


def set_field(doc: Document, index: int, name: str, value: Any,
              merge: bool = True) -> SetFields:
    """Set one field; with merge, consecutive changes of it (a slider drag) merge."""
    return SetFields(index, {name: value}, text=f"Set {name}",
                     merge_key=("field", index, name) if merge else None)


def affine_matrix(translate: Sequence[float] = (0.0, 0.0, 0.0),
                  rotate_degrees: Sequence[float] = (0.0, 0.0, 0.0), scale: float = 1.0,
                  pivot: Sequence[float] = (0.0, 0.0, 0.0)) -> np.ndarray:
    """A 4x4 affine map: scale and rotate (about x, then y, then z, in degrees) around
    `pivot`, then translate."""
    rx, ry, rz = (math.radians(float(v)) for v in rotate_degrees)
    cx, sx, cy, sy, cz, sz = (math.cos(rx), math.sin(rx), math.cos(ry), math.sin(ry),
                              math.cos(rz), math.sin(rz))
    Rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    Ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    Rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    linear = Rz @ Ry @ Rx * float(scale)
    p = np.asarray(pivot, dtype=np.float64).reshape(3)
    m = np.eye(4)
    m[:3, :3] = linear
    m[:3, 3] = p - linear @ p + np.asarray(translate, dtype=np.float64).reshape(3)
    return m


def apply_affine(points: np.ndarray, matrix: np.ndarray) -> np.ndarray:
    """(n, 3) points through a 4x4 affine matrix -> (n, 3)."""
    return points @ matrix[:3, :3].T + matrix[:3, 3]


def transform_primitive(doc: Document, index: int, matrix: np.ndarray,
                        text: str = "Transform primitive",
                        merge_key: Hashable | None = None,
                        profile_scale: float = 1.0) -> SetControlPoints:
    """Map all control points of a primitive through an affine 4x4 matrix; with
    profile_scale != 1 the profile half-axes a, b are multiplied by it in the same step
    (a uniform scale of the whole solid, not only of its axis)."""
    prim = doc.primitive(index)
    points = apply_affine(prim.control_points, np.asarray(matrix, float))
    profile = None
    if float(profile_scale) != 1.0:
        profile = {"a": prim.a * float(profile_scale), "b": prim.b * float(profile_scale)}
    return SetControlPoints(index, points, text=text, merge_key=merge_key, profile=profile)


def new_primitive(doc: Document) -> SweepPrimitive:
    """A default primitive for 'Add': a straight tube through the origin along z."""
    n = len(doc)
    return SweepPrimitive(
        control_points=np.array([[0.0, 0.0, -0.2], [0.0, 0.0, 0.0], [0.0, 0.0, 0.2]]),
        a=0.08, b=0.08, degree=2.0, scaling=(0.0, 0.0), name=doc.next_primitive_name(),
        color=palette_color(n))


def duplicate_primitive(doc: Document, index: int,
                        offset: Sequence[float] = (0.05, 0.05, 0.0)) -> AddPrimitive:
    """A copy of primitive `index`, shifted by `offset` so it can be told apart, inserted
    after it, unlocked and in the next palette colour."""
    prim = doc.primitive(index).copy()
    prim.control_points = prim.control_points + np.asarray(offset, dtype=np.float64)
    prim.name = f"{prim.name or 'primitive'} copy"
    prim.color = palette_color(len(doc))
    prim.locked = False
    return AddPrimitive(prim, index + 1, text="Duplicate primitive")


def apply_fit(doc: Document, primitives: Sequence[SweepPrimitive],
              fit: dict[str, Any] | None = None) -> ReplacePrimitives:
    """Replace the primitives by a fit result (one undo step)."""
    prims = [p.copy() for p in primitives]
    ensure_distinct_colors(prims)
    return ReplacePrimitives(prims, fit=fit, text="Apply fit")


# -- multi-selection, control points, mirroring ------------------------------------------------

def transform_primitives(doc: Document, indices: Sequence[int], matrix: np.ndarray,
                         text: str = "Transform primitives",
                         profile_scale: float = 1.0) -> Command:
    """transform_primitive for each of `indices` (locked ones skipped) as one undo step.
    Raises InvalidPrimitiveError when all of them are locked."""
    unlocked = [i for i in indices if not doc.primitive(i).locked]
    if not unlocked:
        raise InvalidPrimitiveError("the selected primitives are locked: unlock them first")
    parts = [transform_primitive(doc, i, matrix, text=text, profile_scale=profile_scale)
             for i in unlocked]
    return parts[0] if len(parts) == 1 else MacroCommand(parts, text=text)


def set_field_many(doc: Document, indices: Sequence[int], name: str, value: Any) -> Command:
    """Set one field (hide, lock, ...) of several primitives as one undo step."""
    parts: list[Command] = [set_field(doc, i, name, value, merge=False) for i in indices]
    return parts[0] if len(parts) == 1 else MacroCommand(parts, text=f"Set {name}")


def selection_pivot(doc: Document, indices: Sequence[int]) -> np.ndarray:
    """(3,) the centroid of the control points of the given primitives (the origin when
    none): the pivot for rotating or scaling a multi-selection."""
    if not indices:
        return np.zeros(3)
    return np.concatenate([doc.primitive(i).control_points for i in indices]).mean(axis=0)


def insert_control_point(doc: Document, index: int, t: float | None = None) -> SetGeometry:
    """Insert a control point into primitive `index`'s axis at parameter t (the clicked
    point; None: split its longest leg). 3 -> 4 is exact; see geometry.axis_edit."""
    prim = doc.primitive(index)
    if prim.locked:
        raise InvalidPrimitiveError(f"{prim.name or 'the primitive'} is locked: unlock it "
                                    "to add control points", primitive=index)
    try:
        new = axis_edit.insert_control_point(prim, t)
    except ValueError as exc:
        raise InvalidPrimitiveError(f"cannot add a control point here: {exc}",
                                    primitive=index, field="control_points") from exc
    return SetGeometry(index, new.control_points, {"scaling": new.scaling},
                       text="Insert control point")


def delete_control_point(doc: Document, index: int, cp_index: int) -> SetGeometry:
    """Delete control point `cp_index` of primitive `index` (at least 3 stay)."""
    prim = doc.primitive(index)
    if prim.locked:
        raise InvalidPrimitiveError(f"{prim.name or 'the primitive'} is locked: unlock it "
                                    "to delete control points", primitive=index)
    try:
        new = axis_edit.delete_control_point(prim, cp_index)
    except (ValueError, IndexError) as exc:
        raise InvalidPrimitiveError(f"cannot delete this control point: {exc}",
                                    primitive=index, field="control_points") from exc
    return SetGeometry(index, new.control_points, {"scaling": new.scaling},
                       text="Delete control point")


def mirror_selection(doc: Document, indices: Sequence[int], axis: int | str) -> MirrorPrimitives:
    """Mirrored copies of primitives `indices` through the x, y or z plane of the shape's
    frame (exact: that coordinate negated), named '<name> mirror X', unlocked."""
    a = axis_edit.axis_index(axis)
    letter = "XYZ"[a]
    copies = []
    for k, i in enumerate(indices):
        prim = axis_edit.mirror_primitive(doc.primitive(i), a)
        prim.name = f"{prim.name or 'primitive'} mirror {letter}"
        prim.color = palette_color(len(doc) + k)
        prim.locked = False
        copies.append(prim)
    if not copies:
        raise InvalidPrimitiveError("select the primitives to mirror first")
    return MirrorPrimitives(copies, text=f"Mirror {letter}")


def mirror_partners(doc: Document, index: int) -> list[tuple[int, int]]:
    """(j, axis) for every other primitive that is primitive `index` mirrored through
    the plane of `axis` (its geometry, to 1e-9)."""
    prim = doc.primitive(index)
    return [(j, a) for j, other in enumerate(doc.primitives) if j != index
            for a in range(3) if axis_edit.is_mirror_pair(prim, other, a)]


def _mirrored_part(command: Command, partner: int, axis: int) -> Command | None:
    """The edit of `command` (one primitive's geometry) mirrored onto `partner`."""
    if isinstance(command, SetControlPoints):
        return SetControlPoints(partner, axis_edit.mirror_points(command.new, axis),
                                text=command.text, profile=dict(command.new_profile))
    if isinstance(command, SetGeometry):
        return SetGeometry(partner, axis_edit.mirror_points(command.new_points, axis),
                           dict(command.new), text=command.text)
    if isinstance(command, SetFields):
        geometry = {k: v for k, v in command.new.items() if k in GEOMETRY_FIELDS}
        return SetFields(partner, geometry, text=command.text) if geometry else None
    return None


def with_mirror_partners(doc: Document, command: Command) -> Command:
    """`command` plus, for each primitive whose geometry it edits, the mirrored edit of
    its mirror partners (found on the document before the edit) that the command does
    not edit itself and that are not locked: a mirrored pair stays exactly mirrored.
    One undo step; the merge key is kept (with the partner set), so a symmetric drag
    still merges."""
    parts = command.parts if isinstance(command, MacroCommand) else [command]
    edited = {p.index for p in parts if isinstance(p, SetControlPoints | SetGeometry | SetFields)}
    extra: list[Command] = []
    for part in parts:
        if not isinstance(part, SetControlPoints | SetGeometry | SetFields):
            continue
        for j, axis in mirror_partners(doc, part.index):
            if j in edited or doc.primitive(j).locked:  # a locked partner stays as it is
                continue
            mirrored = _mirrored_part(part, j, axis)
            if mirrored is not None:
                extra.append(mirrored)
                edited.add(j)
    if not extra:
        return command
    key = None if command.merge_key is None else ("symmetric", command.merge_key, len(extra))
    return MacroCommand([*parts, *extra], text=command.text, merge_key=key)
