"""The ``hydropump`` command line.

One module per group of sub-commands:

- :mod:`.plant` - ``analyze``, ``simulate``;
- :mod:`.circuit` - ``circuit`` (a circuit file: simulation, the paper's method);
- :mod:`.fit` - ``fit`` (identification from bags);
- :mod:`.calibrate` - ``calibrate``, ``validate`` (the plant model fitted to bags);
- :mod:`.control` - ``design``, ``closed-loop``;
- :mod:`.record` - ``record`` (a recording plan through the ROS nodes, found through an
  entry point: nothing here imports ROS);
- :mod:`._common` - what they share: :class:`~._common.UsageError`, the output folder,
  checks of option values.

Every user mistake (bad parameters, scenario, bag, option value, a missing file) is a
:class:`hydropump_sim.errors.HydropumpError`: :func:`main` prints one ``error:`` line per
problem and exits with code 2. Ctrl-C exits with 130. Anything else is a bug and keeps its
traceback.
"""

from __future__ import annotations

import argparse
import sys

from hydropump_sim.errors import HydropumpError

from . import calibrate, circuit, control, fit, plant, record

# Each adds its sub-commands; a command's ``func(args)`` returns the exit code.
COMMANDS = (plant.register, circuit.register, fit.register, calibrate.register,
            control.register, record.register)

__all__ = ['COMMANDS', 'build_parser', 'main']


def build_parser() -> argparse.ArgumentParser:
    """The parser of every sub-command."""
    ap = argparse.ArgumentParser(prog='hydropump', description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest='command', required=True)
    for register in COMMANDS:
        register(sub)
    return ap


def error_lines(exc: HydropumpError) -> list[str]:
    """The ``error:`` lines of a user error: one per problem, with its source where the
    message would name it."""
    lines = exc.lines or [str(exc)]
    if exc.source and exc.head is None:
        return [f'{exc.source}: {line}' for line in lines]
    return lines


def main(argv=None) -> int:
    """Run ``hydropump`` with ``argv`` (default: the command line); the exit code."""
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except HydropumpError as exc:
        for line in error_lines(exc):
            print(f'error: {line}', file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print('interrupted', file=sys.stderr)
        return 130
