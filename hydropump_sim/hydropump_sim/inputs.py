"""Held inputs: a step schedule as a function of time, the one form every held input of the
suite takes (recordings' currents, scenario steps, campaign commands). Light: no model code,
so that the nodes which only schedule inputs do not load the compiled core."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from .errors import InputError


def held(times, values) -> Callable:
    """A step schedule as a function of time: ``values[k]`` from ``times[k]`` on (the first
    value also before ``times[0]``), as a digital driver holds a set-point.

    Times on a grid such as ``k * dt`` are matched to within a millionth of their spacing,
    so a schedule sampled on its own grid returns its own values.
    """
    ts = np.asarray(times, dtype=float)
    vs = np.asarray(values, dtype=float)
    if ts.ndim != 1 or ts.shape != vs.shape or ts.size == 0:
        raise InputError(f'a held signal needs as many times as values ({ts.size} and '
                         f'{vs.size} given)')
    if np.any(np.diff(ts) <= 0):
        raise InputError('the times of a held signal must increase')
    eps = 1e-6 * (float(np.min(np.diff(ts))) if ts.size > 1 else 1.0)

    def signal(t):
        k = np.searchsorted(ts, np.asarray(t, dtype=float) + eps, side='right') - 1
        v = vs[np.clip(k, 0, vs.size - 1)]
        return v if v.ndim else float(v)
    return signal
