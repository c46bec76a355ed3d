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

from sweepedit.app.document import EDITABLE_FIELDS, Document, Signal, ensure_distinct_colors
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
        a merge key and the gesture is still going on). Raises what check() raises."""
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
