"""Entry point of the ``glove`` command: parses arguments and maps errors to exit codes.

Exit codes (docs/conventions.md): 0 success; 2 bad input or usage, with one clear line on
stderr; 1 internal error (one line; set ``GLOVE_DEBUG=1`` for the traceback).
"""

from __future__ import annotations

import argparse
import os
import sys
import traceback
from collections.abc import Sequence

from glove_cli.commands import (
    bench,
    build,
    calibrate,
    db,
    demo,
    evaluate,
    fingertips,
    pattern,
    render,
    render_sequence,
    track,
)
from glovedb import __version__

COMMANDS = (
    demo,
    render,
    pattern,
    build,
    db,
    bench,
    calibrate,
    track,
    evaluate,
    fingertips,
    render_sequence,
)
# Errors that mean "the input or the request is wrong", not "the program is wrong".
USER_ERRORS = (
    ValueError,
    TypeError,
    FileNotFoundError,
    FileExistsError,
    IsADirectoryError,
    NotADirectoryError,
    PermissionError,
    MemoryError,  # a request too large for this machine (frames, entries)
)


class UsageError(Exception):
    """Raised by the argument parser instead of exiting, so main() owns exit codes."""


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> None:  # type: ignore[override]
        raise UsageError(f"{self.prog}: {message}")


def build_parser() -> argparse.ArgumentParser:
    """The ``glove`` parser with one subparser per command module."""
    parser = _Parser(prog="glove", description="Color-glove hand tracking from RGB-D.")
    parser.add_argument("--version", action="version", version=f"glove {__version__}")
    commands = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    commands.required = True
    for module in COMMANDS:
        module.add_parser(commands)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``glove`` with ``argv`` (default: the process arguments); returns the exit code."""
    try:
        args = build_parser().parse_args(argv)
        return int(args.run(args) or 0)
    except UsageError as error:
        print(error, file=sys.stderr)
        return 2
    except USER_ERRORS as error:
        print(f"glove: error: {error}", file=sys.stderr)
        return 2
    except BrokenPipeError:
        # The reader of our output went away (``glove ... | head``): not an error.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    except KeyboardInterrupt:
        print("glove: interrupted", file=sys.stderr)
        return 130
    except Exception as error:
        if os.environ.get("GLOVE_DEBUG"):
            traceback.print_exc()
        print(f"glove: internal error: {type(error).__name__}: {error}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
