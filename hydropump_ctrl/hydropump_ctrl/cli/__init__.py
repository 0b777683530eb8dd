"""The ``hydropump`` command line.

One module per group of sub-commands:

- :mod:`.plant` - ``analyze``, ``simulate``;
- :mod:`.circuit` - ``circuit`` (a circuit file: simulation, the paper's method);
- :mod:`.fit` - ``fit`` (identification from bags);
- :mod:`.calibrate` - ``calibrate``, ``validate`` (the plant model fitted to bags);
- :mod:`.control` - ``design``, ``closed-loop``;
- :mod:`.sweep` - ``sweep`` (parameter sweeps and tolerance studies on Dask);
- :mod:`.record` - ``record`` (a recording plan through the ROS nodes, found through an
  entry point: nothing here imports ROS);
- :mod:`.options` - what they share: :class:`~.options.UsageError`, the output folder,
  checks of option values.

Every number an option takes is checked as the arguments are parsed (:class:`.options.Number`),
before any work. Every user mistake (bad parameters, scenario, bag, option value, a missing
file) is a :class:`hydropump_sim.errors.HydropumpError`: :func:`main` prints one ``error:`` line
per problem and exits with code 2. Ctrl-C exits with 130, a closed pipe (``| head``) with 141.
Anything else is a bug and keeps its traceback.
"""

from __future__ import annotations

import argparse
import os
import sys

from hydropump_sim.errors import HydropumpError

from . import calibrate, circuit, control, fit, fmu, plant, record, sweep
from .options import Parser

# Each adds its sub-commands; a command's ``func(args)`` returns the exit code.
COMMANDS = (plant.register, circuit.register, fit.register, calibrate.register,
            control.register, record.register, sweep.register, fmu.register)

__all__ = ['COMMANDS', 'build_parser', 'main']


def build_parser() -> argparse.ArgumentParser:
    """The parser of every sub-command."""
    ap = Parser(prog='hydropump', description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest='command', required=True)  # each a Parser too
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
    from .. import provenance
    try:
        args = build_parser().parse_args(argv)  # a refused number is a UsageError
        if argv is not None:
            # Called with its words (from Python, a test): they are the command its reports
            # came from, not this process's.
            provenance.COMMAND[:] = ['hydropump', *map(str, argv)]
        return args.func(args)
    except HydropumpError as exc:
        for line in error_lines(exc):
            print(f'error: {line}', file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print('interrupted', file=sys.stderr)
        return 130
    except BrokenPipeError:
        # The reader has gone (``hydropump design | head``): stop quietly, and let the flush
        # at exit write nowhere rather than fail again. 128 + SIGPIPE, as a shell reports it.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141
