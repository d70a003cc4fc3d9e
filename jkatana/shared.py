"""Where the project's shared external data lives (environment maps, scans, optical constants).

The shared folder sits beside the checkout (``<checkout>/../shared``), or wherever
the environment variable ``JKATANA_SHARED`` points. This is the one place that
rule is written; tests, benchmarks and experiments ask :func:`shared_data` for
their files. The shipped library itself never needs the folder.
"""

from __future__ import annotations

import os
from pathlib import Path

from jkatana.errors import InputError

ENV_VAR = "JKATANA_SHARED"


def shared_root() -> Path:
    """The shared folder: ``$JKATANA_SHARED`` if set, else ``../shared`` beside the checkout."""
    env = os.environ.get(ENV_VAR)
    if env:
        return Path(env)
    return Path(__file__).resolve().parent.parent.parent / "shared"


def shared_data(*parts: str) -> Path:
    """A path under the shared folder's ``data/`` (``shared_data("envmaps", "courtyard.exr")``).

    Raises :class:`~jkatana.errors.InputError` naming the path and the variable
    to set when the path does not exist.
    """
    path = shared_root().joinpath("data", *parts)
    if not path.exists():
        raise InputError(f"shared data not found (set {ENV_VAR} to the shared folder, which holds data/)",
                         path=path)
    return path
