"""Held inputs: a step schedule as a function of time, the one form every held input of the
suite takes (recordings' currents, scenario steps, campaign commands). Light: no model code,
so that the nodes which only schedule inputs do not load the compiled core."""

from __future__ import annotations

from collections.abc import Callable
from typing import Union

import numpy as np

from .errors import InputError

#: An input as the simulations take it: a number, a function of time, held samples, or None.
Signal = Union[float, Callable[[float], float], np.ndarray, None]


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


def sample(signal: Signal, default: float, t: np.ndarray, name: str,
            dt_held: float = 0.0) -> np.ndarray:
    """An input signal on the increment start times ``t``: a number, a callable of time, an
    array held per ``dt_held`` (sample ``k`` from ``k dt_held`` on), or ``None``
    (``default``); :class:`InputError` naming ``name`` if it is not finite."""
    if signal is None:
        return np.full(t.shape, default)
    if isinstance(signal, np.ndarray) and signal.ndim == 1:
        n = int(round(t[-1] / dt_held)) + 1 if t.size else 0
        if signal.size < n:
            raise InputError(f'{name}: {signal.size} held samples cover '
                             f'{signal.size * dt_held:.6g} s; the run needs {n} '
                             f'({n * dt_held:.6g} s at {dt_held:.6g} s a sample)')
        v = np.asarray(held(np.arange(n) * dt_held, signal[:n])(t), dtype=float)
    elif callable(signal):
        try:
            v = np.asarray(signal(t), dtype=float)
            if v.shape != t.shape:
                raise ValueError
        except Exception:
            v = np.array([float(signal(float(tk))) for tk in t])
    else:
        try:
            v = np.full(t.shape, float(signal))
        except (TypeError, ValueError):
            raise InputError(f'{name} must be a number or a function of time, got '
                             f'{signal!r}') from None
    if not np.all(np.isfinite(v)):
        k = int(np.flatnonzero(~np.isfinite(v))[0])
        raise InputError(f'{name} is not finite at t = {t[k]:.6g} s')
    return v
