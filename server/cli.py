"""The `intspace` command line: one sub-command module each under server/commands/."""

from __future__ import annotations

import argparse
import importlib
import sys

# Each module defines register(subparsers) adding its parser with set_defaults(func=...), where
# func(args) returns the process exit code.
_COMMAND_MODULES = (
    "server.commands.calibrate",
    "server.commands.serve",
    "server.commands.db",
    "server.commands.sim",
    "server.commands.node",
    "server.commands.landmark",
)


def build_parser() -> argparse.ArgumentParser:
    """Return the argument parser with every available sub-command registered."""
    parser = argparse.ArgumentParser(
        prog="intspace",
        description="Machine-vision measurement for a home intelligent space.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in _COMMAND_MODULES:
        try:
            module = importlib.import_module(name)
        except ModuleNotFoundError as exc:
            if exc.name == name:  # that command is not part of this installation
                continue
            raise
        module.register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run the command line and return its exit code."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    return int(args.func(args))


if __name__ == "__main__":
    sys.exit(main())
