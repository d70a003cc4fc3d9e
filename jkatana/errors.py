"""Errors jkatana raises for bad input.

Every error about user input names the file, row or field it is about, so the
CLI can print it as one line. They derive from :class:`ValueError` so library
users can catch them the ordinary way.
"""

from __future__ import annotations

from pathlib import Path


class InputError(ValueError):
    """Bad input: names where (file, row, field) and what is wrong."""

    def __init__(self, message: str, *, path: str | Path | None = None,
                 row: int | None = None, field: str | None = None):
        where = []
        if path is not None:
            where.append(str(path))
        if row is not None:
            where.append(f"row {row}")
        if field is not None:
            where.append(f"field {field!r}")
        self.path, self.row, self.field = path, row, field
        super().__init__((": ".join([", ".join(where), message])) if where else message)


class SceneWarning(UserWarning):
    """The scene renders, but very likely not what was meant (one line: cause and fix)."""
