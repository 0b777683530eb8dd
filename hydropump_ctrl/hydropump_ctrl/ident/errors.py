"""The user errors of identification: data that cannot be fitted, and a bag whose data
read but cannot be the pump's.

Both are :class:`~hydropump_sim.errors.HydropumpError` (one line each, shown after ``error:``
by the command line) and ``ValueError`` (bad input values, which is what callers catch);
a bag that cannot be read at all is a :class:`~hydropump_ctrl.bag.BagReadError`, of which
:class:`PlausibilityError` is a kind.
"""

from __future__ import annotations

from hydropump_sim.errors import HydropumpError

from ..bag.errors import BagReadError


class FitError(HydropumpError, ValueError):
    """Data that cannot be identified (no excitation, NaNs, too short, bad options)."""


class PlausibilityError(BagReadError):
    """A bag whose data cannot be what the pump records: wrong units, wrong message types,
    two runs in one bag, too few samples (one line per problem)."""
