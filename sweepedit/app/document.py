"""The document being edited: an Abstraction, its target Shape, file paths, a dirty flag.

Plain data with change notifications and no Qt, so that it (and the command stack that
edits it) can be unit-tested without a display. Views connect to its `Signal`s; only
commands (sweepedit.app.commands) should call the mutators, so that every edit can be
undone.
"""

from __future__ import annotations

import copy
import re
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from sweepedit.errors import primitive_label
from sweepedit.geometry.model import Abstraction, SweepPrimitive, palette_color

# What changed in a primitive (the second argument of Document.primitive_changed).
GEOMETRY = "geometry"  # control points, profile or scaling: re-sweep
DISPLAY = "display"  # colour, visibility, lock: no re-sweep
META = "meta"  # name and other labels

GEOMETRY_FIELDS = frozenset({"a", "b", "degree", "scaling"})
DISPLAY_FIELDS = frozenset({"color", "visible", "locked"})
META_FIELDS = frozenset({"name"})
EDITABLE_FIELDS = GEOMETRY_FIELDS | DISPLAY_FIELDS | META_FIELDS


class Signal:
    """A minimal Qt-free signal: connect callables, emit calls them in order.

    Every slot runs even when one raises: a view that fails must neither keep the others
    from following the document nor turn an edit already applied into an exception in
    the command that applied it (which would leave it out of the undo history). Once
    all have run, the first exception goes to `on_slot_error` when one is given (the
    app reports it), else it is raised."""

    def __init__(self, on_slot_error: Callable[[BaseException], None] | None = None) -> None:
        self._slots: list[Callable[..., Any]] = []
        self.on_slot_error = on_slot_error

    def connect(self, slot: Callable[..., Any]) -> None:
        if slot not in self._slots:
            self._slots.append(slot)

    def disconnect(self, slot: Callable[..., Any]) -> None:
        if slot in self._slots:
            self._slots.remove(slot)

    def receivers(self) -> int:
        """How many slots are connected (as QObject.receivers)."""
        return len(self._slots)

    def emit(self, *args: Any) -> None:
        failed: BaseException | None = None
        # A copy, so that a slot may disconnect itself while the signal is emitted.
        for slot in list(self._slots):
            try:
                slot(*args)
            except Exception as exc:  # the slot's defect, not the edit's
                failed = failed or exc
        if failed is not None:
            if self.on_slot_error is None:
                raise failed
            self.on_slot_error(failed)


class Connections:
    """The slots one view connected to a Document's signals. A Document outlives its
    views (panels, the 3D scene, the heat map), so a view that closes disconnects them
    all: a signal must never call into a view that is gone."""

    def __init__(self) -> None:
        self._links: list[tuple[Signal, Callable[..., Any]]] = []

    def connect(self, signal: Signal, slot: Callable[..., Any]) -> None:
        signal.connect(slot)
        self._links.append((signal, slot))

    def disconnect_all(self) -> None:
        for signal, slot in self._links:
            signal.disconnect(slot)
        self._links.clear()

    def __len__(self) -> int:
        return len(self._links)


def field_kind(name: str) -> str:
    """GEOMETRY, DISPLAY or META for an editable primitive field."""
    if name in GEOMETRY_FIELDS:
        return GEOMETRY
    if name in DISPLAY_FIELDS:
        return DISPLAY
    if name in META_FIELDS:
        return META
    raise KeyError(f"'{name}' is not an editable primitive field")


# "primitive 12", "bar copy 3": a name and the number it ends with.
_NUMBERED = re.compile(r"^(?P<base>.*?)\s*(?P<number>\d+)$")


def unique_name(name: str, taken: Iterable[str]) -> str:
    """`name` itself when no name in `taken` equals it; otherwise its base with the next
    number above every one in use with that base ("primitive 3" among "primitive 1..5"
    gives "primitive 6", "bar copy" gives "bar copy 2")."""
    taken = set(taken)
    if name not in taken:
        return name
    match = _NUMBERED.match(name)
    base = match.group("base") if match else name
    highest = 1
    for other in taken:
        m = _NUMBERED.match(other)
        if m and m.group("base") == base:
            highest = max(highest, int(m.group("number")))
        elif other == base:
            highest = max(highest, 1)
    return f"{base} {highest + 1}".strip()


def ensure_unique_names(primitives: Sequence[SweepPrimitive]) -> None:
    """Name unnamed primitives "primitive i" (from 1, in order) and rename later ones whose
    name an earlier one already has (fit results with residual rounds, files edited by
    hand): the first keeps its name."""
    seen: set[str] = set()
    for i, p in enumerate(primitives):
        name = p.name or primitive_label(i)
        if name in seen:
            name = unique_name(name, seen | {q.name for q in primitives[i + 1:]})
        p.name = name
        seen.add(name)


def ensure_distinct_colors(primitives: Sequence[SweepPrimitive]) -> None:
    """Give primitives palette colours when they all share one (files without colours,
    fit results); a deliberate choice of the user (distinct colours) is left alone.
    Names are made unique too (ensure_unique_names)."""
    if len(primitives) > 1 and len({p.color.lower() for p in primitives}) == 1:
        for i, p in enumerate(primitives):
            p.color = palette_color(i)
    ensure_unique_names(primitives)


class Document:
    """The abstraction being edited and everything the views need to show it.

    Signals:
      primitive_changed(index, kind): one primitive changed; kind is GEOMETRY, DISPLAY or META
      primitives_reset(): primitives added, removed or replaced (indices may have moved)
      selection_changed(index | None): the primary selection (`selection`) or the set of
        selected primitives (`selected_indices`, the primary among them) changed
      shape_changed(): target shape loaded or cleared
      path_changed(): parameter or shape file path changed
      dirty_changed(bool)
      edited(): after any change of the primitives (for metrics)
    """

    def __init__(self, abstraction: Abstraction | None = None) -> None:
        self.abstraction: Abstraction = abstraction if abstraction is not None else Abstraction()
        ensure_unique_names(self.abstraction.primitives)
        self.shape: Any | None = None  # sweepedit.io.shapes.Shape
        self.shape_path: Path | None = None
        self.path: Path | None = None  # the parameter file, once opened or saved
        # Whether abstraction.normalization is the primitives' own frame (a JSON file, a fit,
        # a shape opened first) or only the identity default (the official .txt format and
        # hand-made primitives carry none): a shape opened later lends its frame then.
        self.frame_known = False
        self.dirty = False
        self.selection: int | None = None  # the primary selection (the panels show it)
        # Every selected primitive, in the order selected, the primary last (multi-select).
        self.selected_indices: list[int] = []
        # Where a view's failure to follow a change goes (see Signal); None: raised.
        self.on_view_error: Callable[[BaseException], None] | None = None
        report = self._view_failed
        self.primitive_changed = Signal(report)
        self.primitives_reset = Signal(report)
        self.selection_changed = Signal(report)
        self.shape_changed = Signal(report)
        self.path_changed = Signal(report)
        self.dirty_changed = Signal(report)
        self.edited = Signal(report)

    def _view_failed(self, exc: BaseException) -> None:
        if self.on_view_error is None:
            raise exc
        self.on_view_error(exc)

    # -- reading -------------------------------------------------------------------------
    @property
    def primitives(self) -> list[SweepPrimitive]:
        return self.abstraction.primitives

    def __len__(self) -> int:
        return len(self.abstraction.primitives)

    def primitive(self, index: int) -> SweepPrimitive:
        return self.abstraction.primitives[index]

    @property
    def selected(self) -> SweepPrimitive | None:
        if self.selection is None:
            return None
        return self.abstraction.primitives[self.selection]

    def names(self, skip: int | None = None) -> set[str]:
        """The primitives' names, without the one at index `skip`."""
        return {p.name for i, p in enumerate(self.primitives) if i != skip}

    def next_primitive_name(self) -> str:
        """"primitive N" for a new primitive, N one above the highest number in use (so
        after a .txt's "primitive 1..5", Add makes "primitive 6", also after a delete)."""
        numbers = [int(m.group("number")) for name in self.names()
                   if (m := _NUMBERED.match(name)) and m.group("base") == "primitive"]
        return f"primitive {max(numbers, default=0) + 1}"

    def display_name(self) -> str:
        """A title for the window: the parameter file, else the shape, else 'untitled'."""
        if self.path is not None:
            return self.path.name
        if self.shape_path is not None:
            return self.shape_path.name
        return "untitled"

    # -- whole-document changes (not undoable: opening files) ----------------------------
    def set_abstraction(self, abstraction: Abstraction, path: str | Path | None = None,
                        frame_known: bool = True) -> None:
        """Replace everything edited (after opening a parameter file or starting anew).
        frame_known=False: the file had no normalisation (official .txt), so the target
        shape's is adopted when one is opened."""
        ensure_distinct_colors(abstraction.primitives)
        self.abstraction = abstraction
        self.frame_known = bool(frame_known)
        self.path = Path(path) if path is not None else None
        self.selection = None
        self.selected_indices = []
        self.primitives_reset.emit()
        self.selection_changed.emit(None)
        self.path_changed.emit()
        self.set_dirty(False)
        self.edited.emit()

    def set_shape(self, shape: Any | None, path: str | Path | None = None) -> None:
        """Set the target shape; an empty document, or primitives without a frame of their
        own (official .txt, made by hand), adopt its normalisation."""
        self.shape = shape
        self.shape_path = Path(path) if path is not None else None
        normalization = getattr(shape, "normalization", None)
        if (shape is not None and normalization is not None
                and (not self.primitives or not self.frame_known)):
            self.abstraction.normalization = copy.deepcopy(normalization)
            self.frame_known = True
        if shape is not None and path is not None and self.abstraction.source is None:
            self.abstraction.source = {"path": str(path)}
        self.shape_changed.emit()
        self.path_changed.emit()
        self.edited.emit()

    def set_path(self, path: str | Path | None) -> None:
        self.path = Path(path) if path is not None else None
        self.path_changed.emit()

    def set_dirty(self, dirty: bool) -> None:
        if dirty != self.dirty:
            self.dirty = dirty
            self.dirty_changed.emit(dirty)

    def select(self, index: int | None) -> None:
        """Select one primitive (or none): the primary and the only one selected."""
        if index is not None and not 0 <= index < len(self):
            index = None
        self.set_selection([] if index is None else [index])

    def set_selection(self, indices: Iterable[int], primary: int | None = None) -> None:
        """Select several primitives; `primary` (default: the last of `indices`) is the one
        the panels show and whose handles the scene draws. Invalid indices are dropped."""
        chosen: list[int] = []
        for i in indices:
            if 0 <= int(i) < len(self) and int(i) not in chosen:
                chosen.append(int(i))
        if primary is not None and primary in chosen:
            chosen.remove(primary)
            chosen.append(primary)
        self._set_selection_state(chosen)

    def _set_selection_state(self, chosen: list[int], emit_always: bool = False) -> None:
        primary = chosen[-1] if chosen else None
        changed = chosen != self.selected_indices or primary != self.selection
        self.selected_indices = chosen
        self.selection = primary
        if changed or emit_always:
            self.selection_changed.emit(primary)

    def _remap_selection(self, new_index: Callable[[int], int | None]) -> bool:
        """Move the selection after primitives moved (new_index: old -> new or None when
        gone); True when the primary changed."""
        old = self.selection
        chosen = [j for j in (new_index(i) for i in self.selected_indices) if j is not None]
        self.selected_indices = chosen
        self.selection = chosen[-1] if chosen else None
        return old != self.selection

    # -- mutators used by commands --------------------------------------------------------
    def set_control_points(self, index: int, control_points: np.ndarray,
                           profile: dict[str, float] | None = None) -> None:
        """Replace one primitive's control points by a copy of `control_points` (n, 3),
        and optionally its profile half-axes (`profile` {"a": .., "b": ..}) in the same
        change (scaling a whole primitive): one re-sweep, one notification."""
        prim = self.abstraction.primitives[index]
        prim.control_points = np.array(control_points, dtype=np.float64, copy=True)
        for name, value in (profile or {}).items():
            if name not in ("a", "b"):
                raise KeyError(f"'{name}' is not a profile half-axis")
            setattr(prim, name, float(value))
        self.primitive_changed.emit(index, GEOMETRY)
        self.edited.emit()

    def set_geometry(self, index: int, control_points: np.ndarray,
                     values: dict[str, Any]) -> None:
        """Replace one primitive's control points (any count n >= 3, (n, 3)) and geometry
        fields (a, b, degree, scaling) in one change: one re-sweep, one notification."""
        unknown = set(values) - GEOMETRY_FIELDS
        if unknown:
            raise KeyError(f"not geometry fields: {sorted(unknown)}")
        prim = self.abstraction.primitives[index]
        prim.control_points = np.array(control_points, dtype=np.float64, copy=True)
        for name, value in values.items():
            setattr(prim, name, tuple(float(s) for s in value) if name == "scaling"
                    else float(value))
        self.primitive_changed.emit(index, GEOMETRY)
        self.edited.emit()

    def set_fields(self, index: int, values: dict[str, Any]) -> None:
        """Set editable fields (a, b, degree, scaling, name, color, visible, locked)."""
        prim = self.abstraction.primitives[index]
        kinds = set()
        for name, value in values.items():
            kinds.add(field_kind(name))
            if name == "scaling":
                value = tuple(float(s) for s in value)
            elif name in ("a", "b", "degree"):
                value = float(value)
            elif name in ("visible", "locked"):
                value = bool(value)
            elif name == "name":
                value = unique_name(str(value), self.names(skip=index))
            setattr(prim, name, value)
        # One notification per kind, the most demanding first (a re-sweep redraws all).
        for kind in (GEOMETRY, DISPLAY, META):
            if kind in kinds:
                self.primitive_changed.emit(index, kind)
        self.edited.emit()

    def insert_primitive(self, index: int, primitive: SweepPrimitive) -> None:
        """Insert `primitive` (renamed if its name is taken: names stay unique)."""
        primitive.name = unique_name(primitive.name or self.next_primitive_name(),
                                     self.names())
        self.abstraction.primitives.insert(index, primitive)
        self._remap_selection(lambda i: i + 1 if i >= index else i)
        self.primitives_reset.emit()
        self.edited.emit()

    def remove_primitive(self, index: int) -> SweepPrimitive:
        prim = self.abstraction.primitives.pop(index)
        was = list(self.selected_indices)
        self._remap_selection(lambda i: None if i == index else i - 1 if i > index else i)
        self.primitives_reset.emit()
        if index in was:
            self.selection_changed.emit(self.selection)
        self.edited.emit()
        return prim

    def replace_primitives(self, primitives: Iterable[SweepPrimitive],
                           fit: dict[str, Any] | None = None) -> None:
        """Replace all primitives (and the fit record) at once; names are made unique."""
        self.abstraction.primitives = list(primitives)
        ensure_unique_names(self.abstraction.primitives)
        self.abstraction.fit = fit
        n = len(self)
        was = list(self.selected_indices)
        self._remap_selection(lambda i: i if i < n else None)
        self.primitives_reset.emit()
        if was != self.selected_indices:
            self.selection_changed.emit(self.selection)
        self.edited.emit()
