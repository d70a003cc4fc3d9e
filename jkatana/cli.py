"""The ``jkatana`` command.

Each subcommand is a thin call into the library. Subcommands live next to the
stage they drive (``jkatana/<stage>/commands.py``) and are registered here by
name only, so that ``jkatana --help`` and a single subcommand import nothing but
what they need (JAX start-up is paid only by commands that use it).

A command module provides two functions::

    def add_arguments(parser: argparse.ArgumentParser) -> None: ...
    def run(args: argparse.Namespace) -> int: ...

and a module-level ``HELP`` string.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from jkatana.errors import InputError

# name -> (module, attribute prefix). The prefix lets one module hold several
# commands: ``measure`` and ``simulate`` both live in ``jkatana.measure.commands``
# as ``measure_add_arguments``/``measure_run`` and ``simulate_...``.
COMMANDS: dict[str, tuple[str, str]] = {
    "demo": ("jkatana.render.commands", "demo"),
    "render": ("jkatana.render.commands", "render"),
    "simulate": ("jkatana.measure.commands", "simulate"),
    "measure": ("jkatana.measure.commands", "measure"),
    "fit": ("jkatana.fit.commands", "fit"),
    "report": ("jkatana.fit.commands", "report"),
    "shape": ("jkatana.shape.commands", "shape"),
    "map": ("jkatana.maps.commands", "map"),
    "light": ("jkatana.light.commands", "light"),
    "view": ("jkatana.interactive.commands", "view"),
    "bench": ("benchmarks.__main__", "bench"),
}


def _load(name: str):
    module_name, prefix = COMMANDS[name]
    try:
        module = importlib.import_module(module_name)
    except ModuleNotFoundError as err:  # a stage not built yet, or benchmarks/ outside a checkout
        if err.name and (module_name.startswith(err.name) or err.name.startswith(module_name)):
            return None, prefix
        raise
    return module, prefix


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="jkatana",
        description="Measured spectral reflectance of polished steel: measure, fit, render.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, (module_name, _) in COMMANDS.items():
        if only is not None and name != only:
            sub.add_parser(name, help=f"(see jkatana {name} --help)")
            continue
        module, prefix = _load(name)
        if module is None or not hasattr(module, f"{prefix}_run"):
            continue
        help_text = getattr(module, f"{prefix.upper()}_HELP", None) or module.__doc__ or ""
        p = sub.add_parser(name, help=help_text.strip().splitlines()[0] if help_text else None,
                           description=help_text)
        getattr(module, f"{prefix}_add_arguments")(p)
    return parser


def _one_line_scene_warnings() -> None:
    """Scene warnings (:class:`jkatana.render.check.SceneWarning`) print as one line, like input errors."""
    import warnings

    if getattr(warnings.formatwarning, "_jkatana", False):
        return
    default = warnings.formatwarning

    def fmt(message, category, filename, lineno, line=None):
        if category.__name__ == "SceneWarning":
            return f"jkatana: warning: {message}\n"
        return default(message, category, filename, lineno, line)

    fmt._jkatana = True
    warnings.formatwarning = fmt


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    only = argv[0] if argv and argv[0] in COMMANDS else None
    parser = build_parser(only)
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return 0
    _one_line_scene_warnings()
    module, prefix = _load(args.command)
    if module is None:
        print(f"jkatana: the command {args.command!r} is not available in this build", file=sys.stderr)
        return 2
    try:
        return int(getattr(module, f"{prefix}_run")(args) or 0)
    except InputError as err:  # bad input: one line naming file/row/field, exit 2
        print(f"jkatana {args.command}: error: {err}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
