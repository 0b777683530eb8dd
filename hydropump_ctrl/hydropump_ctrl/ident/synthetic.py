"""Synthetic identification data with a known truth, computed in closed form.

The flow is the continuous-time response of eq. 19 to a current made of a staircase plus a
sinusoidal dither, evaluated analytically at the sample instants (no discretisation, so the
truth does not share any code with the fit): each step contributes
``G0 dU (1 - exp(-(t - t_j - t_d)/tau))`` after ``t_j + t_d``, and the dither its steady
sinusoidal response. The measured flow gets white noise and quantisation; steps fall on the
sample grid, as a digitally commanded current does.

Amplitudes are in the paper's units (current fraction of the 0..100 % displacement range,
flow in % of ``V_p f_p``) and the recordings in SI, through ``current_range`` and ``Q_max``:
a ``solenoid_current`` [A] and a ``line_flow`` [m^3/s]. Test and benchmark data only; the fit
never imports this module.
"""

from __future__ import annotations

from dataclasses import dataclass
import math

import numpy as np

from .recording import Recording

# The reference pump (config/pump.yaml): 0..100 % displacement at 0.3..0.7 A,
# V_p f_p = 1.125e-3 m^3/s.
CURRENT_RANGE = (0.3, 0.7)
Q_MAX = 1.125e-3


@dataclass(frozen=True)
class Truth:
    """Parameters a synthetic record was made with (SI times)."""

    G0: float
    tau: float
    td: float
    offset: float = 0.0


def staircase(duration: float, dt: float, rng: np.random.Generator, *, start: float = 0.4,
              lo: float = 0.15, hi: float = 0.85, dwell=(0.6, 1.2), size=(0.06, 0.2),
              first: float = 0.5) -> list[tuple[float, float]]:
    """Random staircase ``[(t_j, level_j), ...]`` starting at ``(-inf, start)``.

    Step times are whole samples of ``dt``; levels stay in ``[lo, hi]``.
    """
    steps = [(-math.inf, start)]
    t, level = first, start
    while t < duration:
        k = int(round(t / dt))
        amp = rng.uniform(*size)
        sign = rng.choice((-1.0, 1.0))
        if not lo <= level + sign * amp <= hi:
            sign = -sign
        level = min(max(level + sign * amp, lo), hi)
        steps.append((k * dt, level))
        t = k * dt + rng.uniform(*dwell)
    return steps


def level_at(steps, t: np.ndarray) -> np.ndarray:
    """Staircase value at times ``t`` (right-continuous: the new level from ``t_j`` on)."""
    times = np.array([s[0] for s in steps[1:]])
    levels = np.array([s[1] for s in steps])
    return levels[np.searchsorted(times, t, side='right')]


def fopdt_truth(t: np.ndarray, steps, truth: Truth, *, dither_amp: float = 0.0,
                dither_freq: float = 150.0, dither_phase: float = 0.0) -> np.ndarray:
    """Analytic flow [%] of eq. 19 at times ``t`` for a staircase plus sinusoidal dither.

    The system is in steady state at the first level (with the dither running) for
    ``t -> -inf``.
    """
    G0, tau, td = truth.G0, truth.tau, truth.td
    s = np.asarray(t, dtype=float) - td
    x = np.full(s.shape, steps[0][1])
    prev = steps[0][1]
    for tj, lev in steps[1:]:
        on = s > tj
        x[on] += (lev - prev) * (1.0 - np.exp(-(s[on] - tj) / tau))
        prev = lev
    if dither_amp:
        w = 2.0 * math.pi * dither_freq
        x += dither_amp / math.hypot(1.0, w * tau) * np.sin(w * s + dither_phase
                                                             - math.atan(w * tau))
    return truth.offset + G0 * x


def make_record(truth: Truth, *, seed: int, duration: float = 20.0, dt: float = 1e-3,
                noise: float = 0.5, quantum: float = 0.25, dither: float = 0.03,
                dither_freq: float = 150.0, steps=None, name: str = '',
                current_range=CURRENT_RANGE, Q_max: float = Q_MAX, **stair) -> Recording:
    """One synthetic record as a :class:`~.recording.Recording` (SI).

    Parameters
    ----------
    truth : Truth
        ``G0`` [% per unit current], ``tau``, ``td`` [s], ``offset`` [%].
    seed : int
        Seed of the staircase, the dither phase and the noise.
    duration, dt : float
        Record length and sample period [s].
    noise, quantum : float
        White-noise standard deviation and quantisation step of the flow [% of ``V_p f_p``].
    dither : float
        Dither amplitude as a fraction of the current range.
    steps : list, optional
        Staircase ``[(t_j, level_j)]``; default :func:`staircase` with ``**stair``.
    """
    rng = np.random.default_rng(seed)
    if steps is None:
        steps = staircase(duration, dt, rng, **stair)
    phase = rng.uniform(0, 2 * math.pi)
    t = np.arange(int(round(duration / dt))) * dt
    u = level_at(steps, t) + dither * np.sin(2 * math.pi * dither_freq * t + phase)
    y = fopdt_truth(t, steps, truth, dither_amp=dither, dither_freq=dither_freq,
                    dither_phase=phase)
    y = y + rng.normal(0.0, noise, t.size) if noise else y
    if quantum:
        y = quantum * np.round(y / quantum)
    lo, hi = current_range
    return Recording(t, {'solenoid_current': lo + (hi - lo) * u, 'line_flow': Q_max * y / 100.0},
                     name=name or f'synthetic-{seed}',
                     labels={'solenoid_current': 'solenoid current I_s (synthetic)',
                             'line_flow': 'line flow q_l (synthetic)'},
                     topics={'solenoid_current': 'synthetic', 'line_flow': 'synthetic'})


def paper_set(*, seed: int = 5, n: int = 9, spread: bool = False, truth: Truth | None = None,
              **kw) -> tuple[list[Recording], list[Truth]]:
    """The nine-record acceptance set: 20 s at 1 kHz, noise 0.5 %, quantisation 0.25 %,
    3 % dither at 150 Hz, staircases from a non-zero steady state.

    With ``spread`` each record's truth is drawn around ``truth`` with the paper's spread
    (0.7, 2 ms, 5.5 ms).
    """
    base = truth or Truth(100.0, 0.100, 0.055)
    rng = np.random.default_rng(seed)
    truths = []
    for _ in range(n):
        if spread:
            truths.append(Truth(base.G0 + rng.normal(0, 0.7), base.tau + rng.normal(0, 0.002),
                                base.td + rng.normal(0, 0.0055), base.offset))
        else:
            truths.append(base)
    recs = [make_record(tr, seed=seed * 1000 + i, name=f'set{i + 1}', **kw)
            for i, tr in enumerate(truths)]
    return recs, truths


def plant_recording(params, current: np.ndarray, *, load_pressure: np.ndarray | None = None,
                    dt: float = 1e-3, profile=None, name: str = 'plant') -> Recording:
    """A recording of the fine model as the simulator node publishes it: every measured
    signal through the sensor ``profile`` (a :class:`hydropump_sim.sensors.SensorProfile`),
    pressures absolute, the inputs (current, load pressure) stamped with the instant they
    hold from, and the command ``solenoid_current_cmd`` left out (a bench that logs only its
    sensors). Made by the suite's own integrator and sensor models: data for examples and
    benchmarks, not a truth for the fit's tests (those come from ``tests/independent.py``).

    ``current`` is the absolute command [A] held over each sample; ``load_pressure`` gauge
    [Pa] (default: the params file's)."""
    from hydropump_sim.measure import PRESSURE_SIGNALS, SIGNAL_OUTPUTS
    from hydropump_sim.model import OUTPUTS
    from hydropump_sim.sensors import apply_profile
    from hydropump_sim.simulate import simulate

    n = current.size
    res = simulate(params, (n - 1) * dt, current, load_pressure=load_pressure, dt_out=dt,
                   dt_max=dt)
    y = res.y[:n]
    true = {s: (res.P_u[:n] if o is None else y[:, OUTPUTS.index(o)])
            for s, o in SIGNAL_OUTPUTS.items()}
    t = np.arange(n) * dt
    meas = apply_profile(profile, t, true) if profile is not None else true
    p_atm = params.fluid.p_atm
    for s in PRESSURE_SIGNALS:  # absolute, as the topics carry them
        meas[s] = meas[s] + p_atm
    return Recording(t, meas, name=name)
