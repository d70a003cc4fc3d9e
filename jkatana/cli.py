"""The ``jkatana`` command.

Each subcommand is a thin call into the library. Subcommands live next to the
stage they drive (``jkatana/<stage>/commands.py``) and are registered in
:data:`COMMANDS` by module name and prefix only, so that ``jkatana <command>``
imports that command's module alone (JAX start-up is paid only by commands
that use it); ``jkatana --help`` imports them all for their help lines.

A command module provides, for its prefix ``name``::

    def name_add_arguments(parser: argparse.ArgumentParser) -> None: ...
    def name_run(args: argparse.Namespace) -> int: ...

and optionally a module-level ``NAME_HELP`` string (else the module docstring).
``bench`` is the exception: the benchmark suite is not part of the installed
package, and ``jkatana bench`` runs the source checkout's ``benchmarks`` (one
line and exit 2 where there is none). Bad input (:class:`~jkatana.errors.InputError`)
is printed as one line naming the file, row or field, exit status 2.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
import warnings
from pathlib import Path

from jkatana.errors import InputError, SceneWarning
from jkatana.io.interrupt import hold_if_exiting
from jkatana.runtime import compile_cache

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
    "compare": ("jkatana.fit.commands", "compare"),
    "brdf": ("jkatana.brdf.commands", "brdf"),
    "shape": ("jkatana.shape.commands", "shape"),
    "map": ("jkatana.maps.commands", "map"),
    "light": ("jkatana.render.commands", "light"),  # light.commands, and prefilter, which prepares a render
    "view": ("jkatana.interactive.commands", "view"),
    "export": ("jkatana.export.commands", "export"),
    "bench": ("benchmarks.__main__", "bench"),
}


def _checkout_root() -> Path | None:
    """The source checkout this jkatana was imported from, if any: the folder holding both ``jkatana/``
    and ``benchmarks/``. The benchmark suite is not installed with the package; ``jkatana bench`` runs
    the checkout's (as ``python -m benchmarks`` there does)."""
    root = Path(__file__).resolve().parents[1]
    return root if (root / "benchmarks" / "__main__.py").is_file() else None


def _load(name: str):
    module_name, prefix = COMMANDS[name]
    if name == "bench":
        root = _checkout_root()
        if root is None:
            return None, prefix
        if str(root) not in sys.path:
            sys.path.insert(0, str(root))
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
        if name != "bench":
            p.add_argument("--max-memory", default=None, metavar="SIZE",
                           help="refuse requests estimated to need more memory than this (e.g. 8G; "
                                "default: what the machine has available)")
    return parser

def _one_line_scene_warnings() -> None:
    """Scene warnings (:class:`jkatana.errors.SceneWarning`) print as one line, like input errors."""
    if getattr(warnings.formatwarning, "_jkatana", False):
        return
    default = warnings.formatwarning

    def fmt(message, category, filename, lineno, line=None):
        if issubclass(category, SceneWarning):
            return f"jkatana: warning: {message}\n"
        return default(message, category, filename, lineno, line)

    fmt._jkatana = True
    warnings.formatwarning = fmt


def _one_line(err: BaseException) -> str:
    """An OS or decoding error as one line naming the file."""
    if isinstance(err, OSError):
        where = f"{err.filename}: " if err.filename else ""
        return f"{where}{err.strerror or err}"
    if isinstance(err, UnicodeDecodeError):
        return f"not UTF-8 text ({err.reason} at byte {err.start})"
    if isinstance(err, MemoryError):
        return "out of memory (a smaller request, or --max-memory to be refused up front)"
    return str(err).splitlines()[0] if str(err) else type(err).__name__


def main(argv: list[str] | None = None, *, handle_signals: bool | None = None) -> int:
    """Run one command; bad input prints one line and returns 2.

    As a program (``argv`` None, or ``handle_signals``), SIGINT/SIGTERM end the
    command cleanly with 130/143 (:mod:`jkatana.io.interrupt`). Python warnings
    (numpy's RuntimeWarnings, library notices) are not printed unless asked for
    with ``-W``/``PYTHONWARNINGS``: problems they hint at are checked and
    reported as errors.
    """
    if handle_signals is None:
        handle_signals = argv is None
    argv = sys.argv[1:] if argv is None else list(argv)
    command = argv[0] if argv and argv[0] in COMMANDS else None
    if handle_signals:
        from jkatana.io.interrupt import install

        install(command or "")
    if not sys.warnoptions and not os.environ.get("PYTHONWARNINGS"):
        warnings.simplefilter("ignore")
        warnings.simplefilter("always", SceneWarning)  # a scene warning is a message for the user
    for a in argv:
        if "\x00" in a:
            print(f"jkatana{' ' + command if command else ''}: error: an argument contains a NUL byte "
                  f"({a.split(chr(0))[0]!r}...)", file=sys.stderr)
            return 2
    if command == "bench" and _checkout_root() is None:
        print("jkatana bench: error: the benchmark suite runs from a source checkout (benchmarks/ beside "
              "jkatana/); there is none beside this installation", file=sys.stderr)
        return 2
    _one_line_scene_warnings()
    compile_cache()  # before the command's module imports JAX, which reads its cache settings then (jkatana.runtime)
    parser = build_parser(command)
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return 0
    module, prefix = _load(args.command)
    if module is None:
        print(f"jkatana: the command {args.command!r} is not available in this build", file=sys.stderr)
        return 2
    try:
        return _run(args, module, prefix)
    finally:  # returning or unwinding while an interrupt is handled: wait for its clean exit
        hold_if_exiting()
        if handle_signals:  # the command is over: an interrupt during interpreter teardown changes nothing
            import signal

            for sig in (signal.SIGINT, signal.SIGTERM):
                signal.signal(sig, signal.SIG_IGN)


def _run(args: argparse.Namespace, module, prefix: str) -> int:
    """Run the parsed command; bad input → one line, exit 2."""
    try:
        if getattr(args, "max_memory", None) is not None:
            from jkatana.io.limits import parse_size

            args.max_memory = parse_size(args.max_memory)
        return int(getattr(module, f"{prefix}_run")(args) or 0)
    except InputError as err:  # bad input: one line naming file/row/field, exit 2
        hold_if_exiting()
        print(f"jkatana {args.command}: error: {err}", file=sys.stderr)
        return 2
    except (OSError, UnicodeDecodeError, MemoryError) as err:  # a file the system refused, text not UTF-8
        hold_if_exiting()
        print(f"jkatana {args.command}: error: {_one_line(err)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:  # in-process callers; as a program the interrupt module exits first
        print(f"jkatana {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
