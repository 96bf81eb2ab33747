"""The ``reach`` command line.

Every command has ``--help``. Errors from reach (bad configs, files, names)
print one line naming what was wrong and exit with status 2.
"""

from __future__ import annotations

import argparse
import logging
import sys
from collections.abc import Sequence
from typing import Any

from reach.errors import ReachError
from reach.tools.commands import answers, build, inspection, serving
from reach.tools.commands.build import cmd_build
from reach.tools.commands.common import Terminated


def make_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="reach", description="Reachable volumes as adaptive octrees (VATrees): build, inspect and query them.",
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    for add in (*build.COMMANDS, *inspection.COMMANDS, *answers.COMMANDS, *serving.COMMANDS):
        add(sub)
    return parser


LONGEST_WORD = 200  # characters of one word (a path, a value) an error prints; a 40 KB path was printed whole


def _short(message: str) -> str:
    """An error message with each overlong word cut in its middle: it stays one readable line."""
    cut = LONGEST_WORD // 2
    return " ".join(w if len(w) <= LONGEST_WORD else f"{w[:cut]}...({len(w) - 2 * cut} characters)...{w[-cut:]}"
                    for w in message.split(" "))


class _Stderr(logging.StreamHandler):  # type: ignore[type-arg]
    """Writes to the standard error of the moment (a caller may have replaced it since)."""

    reach_cli = True

    @property  # type: ignore[override]
    def stream(self) -> Any:
        return sys.stderr

    @stream.setter
    def stream(self, value: Any) -> None:
        pass


def _say_compiles() -> None:
    """The IK programs' compiles (``oracles.ik.jit``: minutes on a first run) said on standard error, once."""
    log = logging.getLogger("reach.jit")
    if not any(getattr(h, "reach_cli", False) for h in log.handlers):
        handler = _Stderr()
        handler.setFormatter(logging.Formatter("reach: %(message)s"))
        log.addHandler(handler)
        log.setLevel(logging.INFO)


def main(argv: Sequence[str] | None = None) -> int:
    args = make_parser().parse_args(argv)
    _say_compiles()
    try:
        return int(args.func(args))
    except ReachError as exc:
        print(f"reach: error: {_short(str(exc))}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as exc:
        # A build keeps its checkpoint of the last finished depth: --resume goes on from there.
        hint = ("; run the same build with --resume to go on from its last finished depth" if args.func is cmd_build
                else "")
        if isinstance(exc, Terminated):
            print(f"reach: terminated{hint}", file=sys.stderr)
            return 143
        print(f"reach: interrupted{hint}", file=sys.stderr)
        return 130
    except BrokenPipeError:
        # The reader went away (``reach info ... | head``): not an error of ours.
        # Point stdout at /dev/null so that Python's exit flush does not raise again.
        import os

        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0


if __name__ == "__main__":
    sys.exit(main())
