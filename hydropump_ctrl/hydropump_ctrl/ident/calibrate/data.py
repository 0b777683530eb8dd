"""Recordings as the model sees them: held inputs, measured outputs and their noise levels.

A :class:`Experiment` is one recording cut to what the fine model needs:

- **inputs**, held per sample: the commanded current where it was recorded, else the
  measured one (without its dither lines when the model has its own dither), held from its
  stamp (the topic contract: the simulator publishes at ``t_k`` the current it holds from
  ``t_k``, as a command log does); and the load pressure where it was recorded, a
  measurement like the others, which at ``t_k`` is the one of the step that ended there
  (held from ``t_k-1``). A dropped sample of an input is held over (counted); a longer gap
  is refused;
- **outputs**: each measured signal compared (by default the ones a bench measures, not the
  simulator's exact spool and plate positions), gauge, NaN where a sample is missing
  (dropped and counted), each with its noise level (:func:`noise_level`);
- the **initial state** when the run did not start settled.

Every problem a user can cause is a :class:`CalibrationError` naming the recording and
what is accepted. Nothing here imports ROS.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
import math

import numpy as np

from hydropump_sim.measure import (
    BENCH_OUTPUT_SIGNALS,
    CURRENT_SIGNAL,
    LOAD_PRESSURE_SIGNAL,
    OUTPUT_SIGNALS,
    PRESSURE_SIGNALS,
    SIGNALS,
)
from hydropump_sim.params import Params

from ..errors import FitError
from ..plausibility import MIN_SAMPLES
from ..signals import detect_dither

COMMAND_SIGNAL = 'solenoid_current_cmd'
NOISE_FLOOR = 1e-3        # the smallest noise level, relative to a signal's span
MIN_COMPARED = 10         # finite samples a signal needs beyond this to be compared
MAX_HELD_GAP = 5          # missing input samples in a row that are held over, not refused
# The model's output step [s]: a recording sampled more coarsely is simulated this finely, so
# that a fast transient (the line pole, 3.5 ms) behind a fractional delay is sampled where the
# sensor sampled it, not interpolated between coarse samples.
MODEL_DT = 1.0e-3


class CalibrationError(FitError):
    """A calibration that cannot be run or did not converge (one line per problem)."""


@dataclass
class Experiment:
    """One recording as the model sees it: held inputs and weighted measured outputs."""

    name: str
    dt: float
    current: np.ndarray                  # absolute A, held from t[k] to t[k+1]
    load_pressure: np.ndarray | None     # gauge Pa, held; None = the params file's value
    measured: dict[str, np.ndarray]      # SI, gauge pressures, NaN where missing
    sigma: dict[str, float]              # noise level per signal
    current_source: str = ''
    notes: list[str] = field(default_factory=list)
    t0: float = 0.0                      # s, plant time of the first sample (dither phase)
    # The run's initial state, when it did not start settled at its first inputs: the
    # measured plate position (or pump flow) at the start, whose equilibrium it was.
    start_signal: tuple[str, float] | None = None

    def initial_current(self, params: Params) -> float:
        """The current whose equilibrium the run starts from: the first input, or the one the
        measured initial plate position says (``phi_s i_s = K_a x_a`` at ``x_c = 0``, eq. 1;
        from a pump flow through eq. 8)."""
        if self.start_signal is None:
            return float(self.current[0])
        name, v = self.start_signal
        sp = params.spool
        x_a = v if name == 'actuator_position' else params.stroke_scale * (
            v / params.Q_max - 0.5)
        lo, hi = params.I_limits
        return float(min(max(params.I_nominal + sp.K_a * x_a / sp.phi_s, lo), hi))

    @property
    def n(self) -> int:
        return self.current.size

    @property
    def fine(self) -> int:
        """Model output steps per recorded sample (see :data:`MODEL_DT`)."""
        return max(1, int(round(self.dt / MODEL_DT)))

    @property
    def dt_model(self) -> float:
        return self.dt / self.fine

    @property
    def duration(self) -> float:
        return self.n * self.dt


def noise_level(y: np.ndarray) -> float:
    """Noise standard deviation of a sampled signal from its second differences (robust: the
    median absolute deviation), which a smooth response leaves out: for white noise
    ``var(d2 y) = 6 sigma^2``."""
    d2 = np.diff(y[np.isfinite(y)], 2)
    if d2.size < 8:
        return 0.0
    mad = float(np.median(np.abs(d2 - np.median(d2)))) * 1.4826
    return mad / math.sqrt(6.0)


def staircase_of(u: np.ndarray, half: int = 5) -> np.ndarray | None:
    """A measured held input (a staircase of set-points through a noisy sensor) as its held
    levels, or ``None`` when it is not one: the steps are where a running median moves by
    more than eight noise levels across ``2 half`` samples, each level the median between
    them; accepted when what is left is the noise alone.

    A noisy input fed to the model would carry its noise into the outputs (a load pressure's
    noise through the line pole into the line pressure): errors in the variables, which bias
    the line volume and hide from the residuals."""
    from scipy.ndimage import median_filter
    sigma = noise_level(u)
    if sigma <= 0.0 or u.size < 8 * half:
        return None
    m = median_filter(u, size=2 * half + 1, mode='nearest')
    jump = np.zeros(u.size)
    jump[half:-half] = m[2 * half:] - m[:-2 * half]
    hot = np.abs(jump) > 8.0 * sigma
    steps = []
    k = 0
    while k < u.size:
        if not hot[k]:
            k += 1
            continue
        end = k
        while end + 1 < u.size and hot[end + 1]:
            end += 1
        seg = np.arange(max(k - half, 1), min(end + half + 1, u.size))
        du = np.abs(u[seg] - u[seg - 1])
        steps.append(int(seg[int(np.argmax(du))]))
        k = end + 1
    bounds = [0, *sorted(set(steps)), u.size]
    out = np.empty_like(u, dtype=float)
    for a, b in zip(bounds[:-1], bounds[1:]):
        out[a:b] = np.median(u[a:b])
    left = u - out
    return out if float(np.sqrt(np.mean(left ** 2))) <= 1.5 * sigma + 1e-300 else None


def _held_over(name: str, what: str, v: np.ndarray, notes: list) -> np.ndarray:
    """An input with its missing samples held over from the last good one (a dropped
    message of a held signal); refused when a gap is long or the first sample is missing."""
    bad = ~np.isfinite(v)
    if not bad.any():
        return v
    if bad[0]:
        raise CalibrationError(f'{name}: the input {what} has no finite first sample; the '
                               'run must start with its inputs')
    edges = np.flatnonzero(np.diff(np.concatenate([[0], bad.astype(np.int8), [0]])))
    longest = int(np.max(edges[1::2] - edges[0::2]))
    if longest > MAX_HELD_GAP:
        raise CalibrationError(f'{name}: the input {what} has a gap of {longest} samples (NaN '
                               f'or inf); at most {MAX_HELD_GAP} in a row are held over')
    k = np.where(bad, 0, np.arange(v.size))
    np.maximum.accumulate(k, out=k)
    notes.append(f'{name}: {int(bad.sum())} missing sample(s) of {what} held over')
    return v[k]


def _check_time(rec, name: str) -> float:
    t = np.asarray(rec.t, dtype=float)
    if t.size < MIN_SAMPLES:
        raise CalibrationError(f'{name}: {t.size} samples; a calibration needs at least '
                               f'{MIN_SAMPLES} (a few time constants of the plant)')
    d = np.diff(t)
    if not np.all(np.isfinite(t)) or np.any(d <= 0):
        k = int(np.flatnonzero(~np.isfinite(d) | (d <= 0))[0]) + 1
        raise CalibrationError(f'{name}: time does not increase at sample {k} (t = '
                               f'{t[k]:.6g} s after {t[k - 1]:.6g} s); split the recording '
                               'into runs whose time increases')
    dt = float(np.median(d))
    if np.max(np.abs(d - dt)) > 0.01 * dt:
        raise CalibrationError(f'{name}: the samples are not on a uniform grid (period '
                               f'{dt:.6g} s, spread up to {np.max(np.abs(d - dt)):.3g} s)')
    return dt


def experiment_from(rec, base: Params, signals: Sequence[str] | None = None,
                    settled: bool = True) -> Experiment:
    """An :class:`Experiment` from a :class:`~..recording.Recording` (pressures made gauge
    with the params file's ``p_atm``); ``signals`` are the compared outputs (default: those
    of :data:`~hydropump_sim.measure.BENCH_OUTPUT_SIGNALS` the recording has). With
    ``settled`` a run that did not start settled starts from the fine model's equilibrium
    its first samples show; without, the model starts as it initialises (an FMU)."""
    name = rec.name or rec.source or 'recording'
    notes: list[str] = []
    dt = _check_time(rec, name)
    cur, source = _input_current(rec, name, base, dt, notes)
    load = _input_load(rec, name, base, notes)
    measured, sigma = _compared(rec, name, base, signals, notes)
    # A bag in simulation time starts at the simulator's time t0: the model's dither then has
    # the simulator's phase (a bench's dither phase is not known: see docs/identification.md).
    exp = Experiment(name, dt, cur, load, measured, sigma, source, notes,
                     t0=rec.t0_ns * 1e-9 if base.input.dither_amp > 0 else 0.0)
    if settled:
        _settled_start(exp, base)
    return exp


def _input_current(rec, name: str, base: Params, dt: float, notes: list[str]
                   ) -> tuple[np.ndarray, str]:
    """The current that drives the model and the signal it comes from: the command, or
    the measured current as its held levels (its dither lines out where the model has its
    own)."""
    if COMMAND_SIGNAL in rec:
        try:
            return (_held_over(name, COMMAND_SIGNAL, np.array(rec[COMMAND_SIGNAL], float),
                               notes), COMMAND_SIGNAL)
        except CalibrationError as exc:
            if CURRENT_SIGNAL not in rec:
                raise
            # A command that starts late (the controller's first update) or has gaps: the
            # applied current says what the plant got.
            notes.append(f'{exc}; the measured {CURRENT_SIGNAL} is used instead')
    if CURRENT_SIGNAL not in rec:
        raise CalibrationError(f'{name}: no current to drive the model: the recording has '
                               f'{", ".join(rec.signals)}; record {CURRENT_SIGNAL} or '
                               f'{COMMAND_SIGNAL}')
    cur = _held_over(name, CURRENT_SIGNAL, np.array(rec[CURRENT_SIGNAL], float), notes)
    levels = staircase_of(cur) if base.input.dither_amp == 0 else None
    if levels is not None and np.any(levels != cur):
        notes.append(f'{name}: {CURRENT_SIGNAL} taken as its held levels (its sensor '
                     "noise left out of the model's input)")
        cur = levels
    if base.input.dither_amp > 0:
        lines = detect_dither(cur, dt)
        t = np.arange(cur.size) * dt
        for line in lines:
            cur = cur - line.at(t)
        if lines:
            notes.append(f'{name}: took {len(lines)} dither line(s) out of the measured '
                         'current (the model has its own dither)')
    return cur, CURRENT_SIGNAL


def _input_load(rec, name: str, base: Params, notes: list[str]) -> np.ndarray | None:
    """The gauge load pressure as the model's input (its held levels where it is a
    staircase), or ``None`` (the params file's)."""
    if LOAD_PRESSURE_SIGNAL not in rec or not np.isfinite(rec[LOAD_PRESSURE_SIGNAL]).any():
        return None
    load = _held_over(name, LOAD_PRESSURE_SIGNAL, np.array(rec[LOAD_PRESSURE_SIGNAL], float),
                      notes) - base.fluid.p_atm
    # A measured pressure at t_k is the one of the step that ended there (the simulator's
    # measurements; a bench's sampler sees a change between two samples at the later one):
    # as an input it holds from the sample before.
    load = np.append(load[1:], load[-1])
    levels = staircase_of(load)
    if levels is not None:
        n_steps = int(np.count_nonzero(np.diff(levels)))
        notes.append(f'{name}: {LOAD_PRESSURE_SIGNAL} taken as {n_steps + 1} held '
                     "level(s) (its sensor noise left out of the model's input)")
        load = levels
    return load


def _compared(rec, name: str, base: Params, signals: Sequence[str] | None, notes: list[str]
              ) -> tuple[dict, dict]:
    """The compared outputs (gauge pressures; non-finite samples as NaN) and each one's
    noise level, the weight of its residuals."""
    p_atm = base.fluid.p_atm
    explicit = signals is not None
    want = BENCH_OUTPUT_SIGNALS if signals is None else tuple(signals)
    measured = {}
    for s in want:
        if s not in rec:
            continue
        y = np.array(rec[s], float)
        ok = np.isfinite(y)
        if ok.sum() <= MIN_COMPARED:
            if explicit:
                notes.append(f'{name}: {s} has {int(ok.sum())} finite samples: not compared')
            continue
        if not ok.all():
            notes.append(f'{name}: {int((~ok).sum())} missing sample(s) of {s} (NaN or inf) '
                         'left out')
            y[~ok] = np.nan
        measured[s] = y - p_atm if s in PRESSURE_SIGNALS else y
    if not measured:
        present = [s for s in want if s in rec]
        if present:
            # The signals are there but (nearly) empty: say how many samples they have.
            counts = ', '.join(f'{s} {int(np.isfinite(rec[s]).sum())}' for s in present)
            raise CalibrationError(
                f'{name}: no output to compare: finite samples of {counts} of '
                f'{rec.t.size}; a compared signal needs more than {MIN_COMPARED}')
        raise CalibrationError(
            f'{name}: no output to compare: the model is compared on {", ".join(want)}; the '
            f'recording has none of them (its signals: {", ".join(rec.signals)})')
    sigma = {}
    for s, y in measured.items():
        sig = noise_level(y)
        span = float(np.nanmax(y) - np.nanmin(y))
        # A noise-free signal (a simulator's exact joint states) still gets a finite weight:
        # 0.1 % of its span, about what the integrator's tolerance leaves of model error.
        sigma[s] = max(sig, NOISE_FLOOR * max(span, abs(float(np.nanmean(y))) * 1e-2, 1e-300))
    return measured, sigma


def _settled_start(exp: Experiment, base: Params) -> None:
    """Did the run start settled? The plate position (exact state) or the pump flow of the
    first samples (before the plate can have moved) gives the equilibrium it started from."""
    for s, k in (('actuator_position', 3), ('pump_flow', 10)):
        y = exp.measured.get(s)
        if y is not None and np.isfinite(y[:k]).all():
            exp.start_signal = (s, float(np.mean(y[:k])))
            i0 = exp.initial_current(base)
            span = base.current_range[1] - base.current_range[0]
            if abs(i0 - exp.current[0]) > 0.02 * span:
                exp.notes.append(f'{exp.name}: the run did not start settled: it starts from '
                                 f'the equilibrium at {i0:.4g} A (the {s} at the start), its '
                                 f'first input is {exp.current[0]:.4g} A')
            else:
                exp.start_signal = None
            return


def excitation_check(exps: Sequence[Experiment]) -> list[str]:
    """A line per experiment whose inputs do not move (nothing to calibrate on)."""
    out = []
    for e in exps:
        span_i = float(np.ptp(e.current))
        span_p = float(np.ptp(e.load_pressure)) if e.load_pressure is not None else 0.0
        if span_i < 2e-3 and span_p < 1e5:
            out.append(f'{e.name}: no excitation: the current moves by {span_i * 1e3:.3g} mA '
                       f'and the load pressure by {span_p / 1e5:.3g} bar; record a staircase '
                       'or a load-pressure step')
    return out


def check_signals(signals: Sequence[str] | None) -> list[str]:
    """One line for compared signals that are not outputs of the model."""
    bad = [s for s in signals or () if s not in OUTPUT_SIGNALS]
    if not bad:
        return []
    return [f'{" ".join(bad)}: not a compared signal (choose from {", ".join(OUTPUT_SIGNALS)}; '
            f'{", ".join(s for s in SIGNALS if s not in OUTPUT_SIGNALS)} are inputs)']
