"""Errors that reach users: each says which file, which primitive and which field."""

from __future__ import annotations

from pathlib import Path


class SweepeditError(Exception):
    """Base of every error that the CLI and the app show to a user as a message."""


def primitive_label(index: int) -> str:
    """How messages and default names call the primitive at 0-based `index`: people
    count from 1 ("primitive 1" is the first), the same numbering as the app's list."""
    return f"primitive {index + 1}"


class InvalidPrimitiveError(SweepeditError, ValueError):
    """A primitive parameter that is missing, not finite or out of range."""

    def __init__(self, message: str, *, primitive: int | None = None, field: str | None = None):
        self.primitive = primitive
        self.field = field
        self.detail = message
        super().__init__(self._compose(None))

    def _compose(self, path: str | None) -> str:
        where = []
        if path:
            where.append(path)
        if self.primitive is not None:
            where.append(primitive_label(self.primitive))
        if self.field:
            where.append(f"field '{self.field}'")
        return (": ".join([", ".join(where), self.detail])) if where else self.detail

    def in_file(self, path: str | Path) -> FileFormatError:
        """The same problem, reported against a file."""
        return FileFormatError(path, self._compose(None), primitive=self.primitive,
                               field=self.field)


class FileFormatError(SweepeditError, ValueError):
    """A file that cannot be read: malformed, truncated, unknown version, bad values."""

    def __init__(self, path: str | Path, message: str, *, primitive: int | None = None,
                 field: str | None = None):
        self.path = str(path)
        self.primitive = primitive
        self.field = field
        self.detail = message
        super().__init__(f"{self.path}: {message}")


class DegenerateShapeError(FileFormatError):
    """A shape file that reads but gives a fit nothing to do: flat, a line, a few points,
    an open sheet or specks that enclose (almost) no volume on the fitting grid."""
