"""The signals a fit works on: the paper's units, data checks, dither lines and steps.

Owns the normalisation of a recording's current and flow to the paper's units (the only place
they are used: everything else is SI), the checks that refuse data a fit cannot use, the
delay and time-constant bounds that fit a record, the detection of sinusoidal dither lines in
the current, and the step instants of a (dithered) staircase, found on a 20 ms centred average
(:func:`smooth`) that also serves the report's figures.
"""

from __future__ import annotations

from dataclasses import dataclass
import functools
import math

import numpy as np
from scipy import fft as sfft
from scipy import optimize

from hydropump_sim.metrics import moving_average

from .errors import FitError
from .plausibility import MIN_SAMPLES

# 20 ms spans three periods of the 150 Hz dither, so it cancels in the average.
SMOOTH_SPAN = 0.02


# --------------------------------------------------------------------------------------------
# The paper's units (only at this edge)
# --------------------------------------------------------------------------------------------

@functools.lru_cache(maxsize=1)
def load_default_params():
    """Plant parameters of ``config/pump.yaml`` (or ``$HYDROPUMP_PARAMS``)."""
    from hydropump_sim.params import default_params_path, load_params
    return load_params(default_params_path())


def normalise(rec, params=None) -> tuple[np.ndarray, np.ndarray]:
    """Current as a fraction of the 0..100 % displacement range, flow in % of ``V_p f_p``.

    ``rec`` is a :class:`~hydropump_ctrl.ident.recording.Recording`; its ``current`` and
    ``flow`` are the signals that act as the current [A] and the flow [m^3/s]. With these
    units a full-range gain is ``G0 = 100``, as in the paper.
    """
    from hydropump_sim.scaling import displacement_of_current, flow_percent
    params = load_default_params() if params is None else params
    return (np.asarray(displacement_of_current(params, rec.current)),
            np.asarray(flow_percent(params, rec.flow)))


# --------------------------------------------------------------------------------------------
# Smoothing and steps
# --------------------------------------------------------------------------------------------

def smoothing_width(dt: float, span: float = SMOOTH_SPAN) -> int:
    """Samples of ``span`` seconds (at least one)."""
    return max(1, int(round(span / dt)))


def smooth(x: np.ndarray, dt: float, span: float = SMOOTH_SPAN) -> np.ndarray:
    """Centred average over ``span`` (an odd number of samples: no phase shift).

    The window shrinks at the ends: the edges keep some dither, which neither the step
    detection nor a plot minds.
    """
    return moving_average(x, smoothing_width(dt, span) | 1, edges='shrink')


def peaks(x: np.ndarray, height: float, distance: int) -> np.ndarray:
    """Indices of the local maxima of ``x`` at least ``height`` high and ``distance`` samples
    apart, the higher kept first; a flat top at its middle, none at an end: the rule of
    ``scipy.signal.find_peaks(x, height=, distance=)``, whose module costs every command
    that finds steps half a second to import."""
    d = np.diff(x)
    turns = np.flatnonzero(d)
    up = np.sign(d[turns])
    k = np.flatnonzero((up[:-1] > 0) & (up[1:] < 0))
    at = (turns[k] + 1 + turns[k + 1]) // 2
    at = at[x[at] >= height]
    keep = np.ones(at.size, bool)
    for j in np.argsort(x[at], kind='stable')[::-1]:
        if keep[j]:
            near = np.abs(at - at[j]) < distance
            near[j] = False
            keep &= ~near
    return at[keep]


def find_steps(u: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Step instants (sample indices) and signed sizes of a (dithered) staircase input."""
    h = smoothing_width(dt)
    us = smooth(u, dt)
    jump = np.zeros_like(us)
    jump[h:-h] = us[2 * h:] - us[:-2 * h]
    mag = np.abs(jump)
    if mag.max() <= 0:
        return np.array([], dtype=int), np.array([])
    cand = peaks(mag, 0.3 * mag.max(), 2 * h + 1)
    idx, size = [], []
    for k in cand:
        # The step sample is where the raw input jumps most near the smoothed edge.
        seg = slice(max(k - h - 1, 1), min(k + h + 2, u.size))
        du = np.diff(u[seg.start - 1:seg.stop]) * np.sign(jump[k])
        idx.append(seg.start + int(np.argmax(du)))
        size.append(jump[k])
    return np.array(idx), np.array(size)


# --------------------------------------------------------------------------------------------
# Data checks and bounds
# --------------------------------------------------------------------------------------------

def check_data(u, y, dt: float, *, min_excitation: float = 0.02) -> tuple[np.ndarray,
                                                                           np.ndarray]:
    """Validate normalised data; raise :class:`FitError` with one line on a problem.

    Parameters
    ----------
    u, y : array_like
        Current fraction and flow [%].
    dt : float
        Sample period [s].
    min_excitation : float
        Least peak-to-peak change of the smoothed current, as a fraction of the current
        range (the dither alone does not identify a 100 ms lag).
    """
    u = np.asarray(u, dtype=float)
    y = np.asarray(y, dtype=float)
    if u.ndim != 1 or u.shape != y.shape:
        raise FitError(f'current and flow must be 1-D arrays of equal length, got {u.shape} '
                       f'and {y.shape}')
    if not (math.isfinite(dt) and dt > 0):
        raise FitError(f'sample period must be positive, got {dt!r}')
    for name, arr in (('current', u), ('flow', y)):
        bad = ~np.isfinite(arr)
        if bad.any():
            k = int(np.flatnonzero(bad)[0])
            raise FitError(f'{name} has {int(bad.sum())} NaN or infinite samples (first at '
                           f't = {k * dt:.6g} s)')
    if u.size < MIN_SAMPLES:
        raise FitError(f'only {u.size} samples: a fit needs a record of at least {MIN_SAMPLES} '
                       'samples')
    us = smooth(u, dt)
    span = float(us.max() - us.min())
    if span < min_excitation:
        raise FitError(f'no excitation: the current moves by {100 * span:.2g} % of its range '
                       f'(at least {100 * min_excitation:g} % needed); record current steps')
    return u, y


def default_bounds(duration: float, dt: float, td_bounds=None, tau_bounds=None
                   ) -> tuple[tuple[float, float], tuple[float, float]]:
    """Delay and time-constant bounds [s]: given ones, or defaults fitting the record."""
    if td_bounds is None:
        td_bounds = (0.0, min(0.25, duration / 8.0))
    if tau_bounds is None:
        tau_bounds = (dt / 4.0, min(2.0, duration / 4.0))
    td_lo, td_hi = (float(b) for b in td_bounds)
    tau_lo, tau_hi = (float(b) for b in tau_bounds)
    # The optimisers take finite bounds only.
    if not 0.0 <= td_lo < td_hi < math.inf:
        raise FitError(f'td bounds must satisfy 0 <= lower < upper < inf, got {td_bounds}')
    if not 0.0 < tau_lo < tau_hi < math.inf:
        raise FitError(f'tau bounds must satisfy 0 < lower < upper < inf, got {tau_bounds}')
    if td_hi > duration / 4.0:
        raise FitError(f'the record ({duration:.3g} s) is too short for a delay bound of '
                       f'{td_hi:.3g} s: it must be at least 4 times the bound')
    return (td_lo, td_hi), (tau_lo, tau_hi)


# --------------------------------------------------------------------------------------------
# Dither
# --------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class Dither:
    """A sinusoidal dither ``amp sin(2 pi freq t + phase)`` on the current (``t`` from the
    record's first sample, ``amp`` in current fraction)."""

    freq: float
    amp: float
    phase: float

    def at(self, t: np.ndarray) -> np.ndarray:
        return self.amp * np.sin(2.0 * math.pi * self.freq * t + self.phase)


def detect_dither(u, dt: float, *, min_ratio: float = 100.0, max_lines: int = 3,
                  min_freq: float = 20.0, min_amp: float = 5e-4) -> list[Dither]:
    """Find sinusoidal dither lines in a (staircase) current.

    The differenced current turns the staircase into isolated spikes (a flat spectrum) and
    keeps a sinusoid a spectral line. A line whose periodogram stands ``min_ratio`` times
    above the median, between ``min_freq`` and Nyquist (an aliased dither shows at its
    alias), is refined in frequency and fitted by least squares on the differences, leaving
    out the step samples; then the next line is sought (harmonics of a non-sinusoidal
    dither), up to ``max_lines``. ``min_freq`` keeps a slow sinusoidal excitation (a test
    signal inside the plant's 1.6 Hz bandwidth) from being taken for dither; lines below
    ``min_amp`` (current fraction; 0.05 %, below the bench's quantum) are left alone.
    """
    u = np.asarray(u, dtype=float)
    t = np.arange(u.size) * dt
    lines: list[Dither] = []
    du = np.diff(u)
    n = du.size
    if n < 64:
        return lines
    nfft = sfft.next_fast_len(4 * n)
    fr = np.fft.rfftfreq(nfft, dt)
    band = fr >= min_freq
    win = np.hanning(n)
    kk = np.arange(n) * dt
    for _ in range(max_lines):
        P = np.abs(np.fft.rfft((du - du.mean()) * win, nfft)) ** 2
        pb = np.where(band, P, 0.0)
        k = int(np.argmax(pb))
        # A line stands out of the floor and is a peak, not the skirt of a slow signal's
        # spectrum at the band's lower edge.
        if pb[k] < min_ratio * float(np.median(P[band])) or not band[k - 1]:
            break
        df = fr[1] - fr[0]
        lo_f, hi_f = max(fr[k] - df, min_freq), min(fr[k] + df, 0.5 / dt)
        f0 = optimize.minimize_scalar(
            lambda f, du=du: -abs(np.sum(du * np.exp(-2j * math.pi * f * kk))),
            bounds=(lo_f, hi_f),
            method='bounded', options={'xatol': 1e-7 * fr[k]}).x
        w = 2.0 * math.pi * f0
        B = np.column_stack([np.diff(np.sin(w * t)), np.diff(np.cos(w * t))])
        keep = np.ones(n, bool)
        for _ in range(3):
            coef, *_ = np.linalg.lstsq(B[keep], du[keep], rcond=None)
            res = du - B @ coef
            mad = float(np.median(np.abs(res[keep]))) * 1.4826 + 1e-15
            keep = np.abs(res) <= 6.0 * mad
        # amp sin(wt + phase) = (amp cos phase) sin wt + (amp sin phase) cos wt
        line = Dither(freq=float(f0), amp=float(math.hypot(*coef)),
                      phase=float(math.atan2(coef[1], coef[0])))
        if line.amp < min_amp:
            break
        lines.append(line)
        du = du - np.diff(line.at(t))
    return lines


def dither_lines(u: np.ndarray, dt: float, dither) -> list[Dither]:
    """The dither lines a fit takes out: ``'auto'`` finds them, a list is used as given,
    ``None`` means none (the whole current is held)."""
    if isinstance(dither, str):
        if dither != 'auto':
            raise FitError(f"dither must be 'auto', a list of Dither or None, got {dither!r}")
        return detect_dither(u, dt)
    return list(dither or [])
