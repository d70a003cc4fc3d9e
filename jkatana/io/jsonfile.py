"""The one reader of JSON inputs: every JSON file a command reads goes through :func:`read_json`.

It turns each way a file can fail to be JSON into one :class:`~jkatana.errors.InputError`
naming the file: unreadable, not UTF-8, malformed (with the line), and the
literals ``NaN``, ``Infinity`` and ``-Infinity``, which Python's ``json``
accepts but RFC 8259 (§6) does not; jkatana writes ``null`` where a value
is undefined (:func:`jkatana.fit.params.write_params`), so such a literal
was put there by hand or by another program, and is refused naming the
field it sits in (``values.mu``). :func:`expect` checks the shape of one
value (an object where an object belongs), naming the field as well.
"""

from __future__ import annotations

import json
from pathlib import Path

from jkatana.errors import InputError


class _Constant:
    """A ``NaN``/``Infinity`` literal seen while parsing (refused after, naming its field)."""

    def __init__(self, text: str):
        self.text = text


def _find_constant(value, where: str = "") -> tuple[str, str] | None:
    if isinstance(value, _Constant):
        return where or "(top level)", value.text
    if isinstance(value, dict):
        for k, v in value.items():
            found = _find_constant(v, f"{where}.{k}" if where else str(k))
            if found:
                return found
    elif isinstance(value, list):
        for i, v in enumerate(value):
            found = _find_constant(v, f"{where}[{i}]")
            if found:
                return found
    return None


def read_json(path: str | Path, what: str = "a JSON file"):
    """The parsed content of the JSON file ``path``; :class:`InputError` naming the file (and field) if it is not JSON.

    ``what`` names the kind of file in the messages ("a parameter file").
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise InputError(f"not found ({what})", path=path) from None
    except IsADirectoryError:
        raise InputError(f"is a folder, not {what}", path=path) from None
    except OSError as err:
        raise InputError(f"cannot read: {err.strerror or err}", path=path) from None
    except UnicodeDecodeError:
        raise InputError(f"not UTF-8 text ({what} is JSON)", path=path) from None
    try:
        data = json.loads(text, parse_constant=_Constant)
    except json.JSONDecodeError as err:
        raise InputError(f"not JSON ({err.msg} at line {err.lineno})", path=path) from None
    except RecursionError:
        raise InputError("nested too deeply to be " + what, path=path) from None
    found = _find_constant(data)
    if found:
        raise InputError(f"{found[1]} is not a JSON number (RFC 8259); write a number, or null where a value "
                         "is undefined", path=path, field=found[0])
    return data


_KINDS = {dict: "an object", list: "an array", str: "a string", bool: "true or false"}


def expect(value, kind: type, field: str, path=None, *, optional: bool = False):
    """``value`` if it is of JSON kind ``kind`` (dict, list, str, bool) or, with ``optional``, None;
    else :class:`InputError` naming ``field``."""
    if value is None and optional:
        return None
    if not isinstance(value, kind) or (kind is not bool and isinstance(value, bool)):
        got = "missing" if value is None else f"got {type(value).__name__} {_short(value)}"
        raise InputError(f"must be {_KINDS.get(kind, kind.__name__)}, {got}", path=path, field=field)
    return value


def _short(value) -> str:
    text = json.dumps(value, default=str)
    return text if len(text) <= 40 else text[:37] + "..."


__all__ = ["read_json", "expect"]
