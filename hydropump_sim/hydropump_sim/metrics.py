"""Step-response figures (63 % time, rise, overshoot, settling, IAE, fast-drop fraction) and
the one smoothing helper of the project: a centred moving average that takes the dither out."""

from __future__ import annotations

from dataclasses import dataclass
import math

import numpy as np


def crossing_time(t: np.ndarray, y: np.ndarray, level: float, t_from: float = 0.0,
                  rising: bool | None = None) -> float:
    """First time at or after ``t_from`` where ``y`` reaches ``level`` (linear interpolation).

    ``rising`` says from which side (default: from the side ``y`` starts on; give it for noisy
    signals, whose first sample may already lie beyond a level close to the start). Returns
    ``nan`` when ``y`` never reaches the level.
    """
    t = np.asarray(t, dtype=float)
    y = np.asarray(y, dtype=float)
    k0 = int(np.searchsorted(t, t_from))
    if k0 >= t.size:
        return math.nan
    if rising is None:
        rising = level >= y[k0]
    hit = (y[k0:] >= level) if rising else (y[k0:] <= level)
    idx = np.flatnonzero(hit)
    if idx.size == 0:
        return math.nan
    k = k0 + int(idx[0])
    if k == k0:
        return float(t[k0])
    y0, y1 = y[k - 1], y[k]
    return float(t[k - 1] + (level - y0) / (y1 - y0) * (t[k] - t[k - 1]))


def _before(y: np.ndarray, k0: int) -> float:
    """Value just before the step: an algebraic output may already jump at the step sample."""
    return float(y[max(k0 - 1, 0)])


@dataclass(frozen=True)
class StepFigures:
    """Figures of one step response; times are measured from the step time, in s."""

    initial: float
    final: float
    t63: float
    rise: float          # 10-90 %
    overshoot: float     # % of the step, beyond the final value
    undershoot: float    # % of the step, opposite to the step direction at the start
    settling: float      # time to stay within +-band of the final value
    iae: float           # integral of |y - final| after the step, in (unit * s)


def step_figures(t, y, t_step: float = 0.0, *, final: float | None = None,
                 initial: float | None = None, band: float = 0.02,
                 band_abs: float | None = None) -> StepFigures:
    """Figures of a step response ``y(t)`` to a step applied at ``t_step``.

    ``initial`` defaults to the value at the step, ``final`` to the last value. The settling
    band is ``band`` times the step size, or ``band_abs`` in the signal's unit.
    """
    t = np.asarray(t, dtype=float)
    y = np.asarray(y, dtype=float)
    k0 = min(int(np.searchsorted(t, t_step)), t.size - 1)
    y0 = _before(y, k0) if initial is None else initial
    yf = float(y[-1]) if final is None else final
    step = yf - y0
    if step == 0.0:
        raise ValueError('step of zero size: no step figures')
    after = y[k0:]
    ta = t[k0:]
    up = step > 0
    t10 = crossing_time(t, y, y0 + 0.1 * step, t_step, up)
    t90 = crossing_time(t, y, y0 + 0.9 * step, t_step, up)
    t63 = crossing_time(t, y, y0 + 0.632 * step, t_step, up) - t_step
    norm = (after - y0) / step
    overshoot = max(0.0, float(np.max(norm)) - 1.0) * 100.0
    undershoot = max(0.0, -float(np.min(norm))) * 100.0
    tol = band * abs(step) if band_abs is None else band_abs
    outside = np.flatnonzero(np.abs(after - yf) > tol)
    if outside.size == 0:
        settling = 0.0
    elif outside[-1] == after.size - 1:
        settling = math.inf
    else:
        settling = float(ta[outside[-1] + 1] - t_step)
    iae = float(np.trapezoid(np.abs(after - yf), ta))
    return StepFigures(y0, yf, t63, t90 - t10, overshoot, undershoot, settling, iae)


def fast_fraction(t, y, t_step: float, fit_window: tuple[float, float]) -> tuple[float, float]:
    """Split a step response into an instantaneous part and one exponential.

    Fits ``y - y_final = a exp(-(t - t_step)/tau)`` over ``fit_window`` (s after the step) and
    extrapolates to the step time. Returns ``(fraction of the step that is instantaneous,
    tau)``; for a falling-flow step of eq. 15 the fraction is the zero's feedthrough.
    """
    t = np.asarray(t, dtype=float)
    y = np.asarray(y, dtype=float)
    k0 = int(np.searchsorted(t, t_step))
    y0, yf = _before(y, k0), float(y[-1])
    sel = (t >= t_step + fit_window[0]) & (t <= t_step + fit_window[1])
    r = (y[sel] - yf) / (y0 - yf)
    slope, icpt = np.polyfit(t[sel] - t_step, np.log(r), 1)
    return 1.0 - math.exp(icpt), -1.0 / slope


# --- smoothing -------------------------------------------------------------------------------

EDGES = ('full', 'shrink', 'valid')


def dither_window(dt: float, f_dither: float, max_periods: int = 10) -> int:
    """Samples of the shortest window that spans a whole number of dither periods.

    Of 1..``max_periods`` periods, the count whose length in samples is closest to a whole
    number (3 periods = 20 samples for 150 Hz at 1 kHz): an average over it cancels the dither
    and its harmonics. ``f_dither <= 0`` gives 1 (no smoothing).
    """
    if f_dither <= 0.0:
        return 1
    per = 1.0 / (f_dither * dt)
    k = min(range(1, max_periods + 1), key=lambda k: abs(k * per - round(k * per)))
    return max(int(round(k * per)), 1)


def moving_average(y, width: int, *, edges: str = 'full') -> np.ndarray:
    """Centred moving average of ``width`` samples (zero phase for an odd width).

    Sample ``k`` is the mean of ``y[k - width // 2 : k - width // 2 + width]``; an even width
    is centred half a sample before ``k``. ``edges`` says what the first and last ``width // 2``
    samples get:

    ``'full'``
        The nearest full window (never a partial one, which would weigh one phase of a ripple
        twice).
    ``'shrink'``
        The part of the window inside the record.
    ``'valid'``
        Nothing: the result holds only the samples with a whole window, ``width - 1`` fewer,
        the first of them sample ``width // 2``.

    A width below 2, or longer than ``y``, returns ``y`` unchanged (as floats).
    """
    if edges not in EDGES:
        raise ValueError(f'edges must be one of {", ".join(EDGES)}, got {edges!r}')
    y = np.asarray(y, dtype=float)
    w = int(width)
    if w < 2 or y.size < w:
        return y
    # Element j of the full convolution is the sum of y[j - w + 1 : j + 1] (zeros outside):
    # a direct sum per sample, no running sum to accumulate rounding over a long record.
    s = np.convolve(y, np.ones(w), mode='full')
    if edges == 'valid':
        return s[w - 1:y.size] / w
    start = np.arange(y.size) - w // 2
    if edges == 'full':
        start = np.clip(start, 0, y.size - w)
        return s[start + w - 1] / w
    count = np.clip(start + w, 0, y.size) - np.clip(start, 0, y.size)
    return s[start + w - 1] / count
