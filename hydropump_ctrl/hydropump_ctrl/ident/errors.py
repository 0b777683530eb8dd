"""The user errors of identification: a bag that cannot be read, data that cannot be fitted.

Both are :class:`~hydropump_sim.errors.HydropumpError` (one line each, shown after ``error:``
by the command line) and ``ValueError`` (bad input values, which is what callers catch);
:class:`PlausibilityError` is the bag error of data that read but cannot be the pump's.
"""

from __future__ import annotations

from hydropump_sim.errors import HydropumpError


class BagError(HydropumpError, ValueError):
    """A bag or saved recording that cannot be read as asked."""


class FitError(HydropumpError, ValueError):
    """Data that cannot be identified (no excitation, NaNs, too short, bad options)."""


class PlausibilityError(BagError):
    """A bag whose data cannot be what the pump records: wrong units, wrong message types,
    two runs in one bag, too few samples (one line per problem)."""
