"""The ``qz`` command.

The application layer: nothing in the package imports it. Each command group is a module with
``register(subparsers)`` that sets ``func(args) -> exit code`` on its parsers; the groups are
listed in ``COMMAND_GROUPS`` (a group that fails to import fails the command, it is never
skipped). Building the parser imports only what parsing needs: a command imports what it runs
(matplotlib, pydrake, scipy, torch, ...) when it runs, so that ``qz --help`` and a mistyped
option are answered at once. Errors a user can cause (QzError) print one line and exit with
status 2; a failed solve or a fall is a reported outcome with exit status 1.
"""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import threading

from qz_drake.cli import blc, capability, classification, core, experiments, hardware, plan, planning
from qz_drake.cli.arguments import OneLineParser, PackageVersion, check_output_argument
from qz_drake.errors import QzError

# In the order of `qz --help`.
COMMAND_GROUPS = (core, blc, planning, plan, classification, capability, hardware, experiments)


def build_parser():
    parser = OneLineParser(prog="qz", description=__doc__.splitlines()[0])
    parser.add_argument("--version", action=PackageVersion)
    sub = parser.add_subparsers(dest="command", required=True, parser_class=OneLineParser)
    for group in COMMAND_GROUPS:
        group.register(sub)
    return parser


@contextlib.contextmanager
def _sigterm_interrupts():
    """A SIGTERM (a job ending, a plain ``kill``) interrupts the command as Ctrl-C does, so that
    it stops the same way: what finished is kept, and one line is printed, not the default
    silent death. Yields the signals received (the exit status is 128 + the signal's number)."""
    received = []

    def interrupt(signum, frame):
        received.append(signum)
        raise KeyboardInterrupt

    if threading.current_thread() is not threading.main_thread():  # only the main thread may
        yield received
        return
    previous = signal.signal(signal.SIGTERM, interrupt)
    try:
        yield received
    finally:
        signal.signal(signal.SIGTERM, previous)


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    with _sigterm_interrupts() as received:
        return _run(args, received)


def _run(args, received: list) -> int:
    try:
        check_output_argument(args)
        return int(args.func(args))
    except QzError as e:
        print(f"qz {args.command}: error: {e}", file=sys.stderr)
        return 2
    except UnicodeDecodeError as e:
        # A binary file where a text file was meant, read by a loader that did not name it.
        print(f"qz {args.command}: error: a file given is not UTF-8 text (byte 0x{e.object[e.start]:02x} at "
              f"offset {e.start}); expected a text file", file=sys.stderr)
        return 2
    except BrokenPipeError:
        # The reader went away (`qz ... | head`): stop quietly, as Unix tools do, and keep
        # the interpreter's final flush from failing on the closed pipe.
        import os

        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141
    except KeyboardInterrupt:  # Ctrl-C or SIGTERM (collections write what finished first)
        print(f"qz {args.command}: interrupted", file=sys.stderr)
        return 128 + (received[-1] if received else signal.SIGINT)
    except OSError as e:
        # A file the user named cannot be read or written (a folder where a file was meant, no
        # permission, a full disk): the same one line as for any other bad input.
        where = f"{e.filename}: " if e.filename else ""
        print(f"qz {args.command}: error: {where}{e.strerror or e}", file=sys.stderr)
        return 2

