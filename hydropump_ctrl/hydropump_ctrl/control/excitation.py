"""Open-loop excitation for identification experiments: staircases, PRBS, chirp and sine.

Each signal is a pure function of the time since the experiment started, so it is reproducible
from its parameters alone (the ``seed`` fixes the random parts: the PRBS register and the
up/down order of the staircase). Levels, offsets and amplitudes are given in percent of
displacement (converted with the eq. 11 static map of the embedded model) or in amperes;
the result is always the absolute solenoid current in A.
"""

from __future__ import annotations

import math

import numpy as np

from .embedded import PumpModel
from .schema import Excitation


class ExcitationSignal:
    """Absolute current [A] of an excitation as a function of time [s].

    Parameters
    ----------
    cfg : Excitation
        The ``excitation`` group of the controller configuration.
    pump : PumpModel
        Embedded model, for the percent-of-displacement to current conversion (eq. 11).

    Attributes
    ----------
    duration : float
        Length of one pass [s] (``inf`` for the sine).
    """

    def __init__(self, cfg: Excitation, pump: PumpModel, present: float | None = None):
        self.cfg = cfg
        self.pump = pump
        # A relative excitation is centred on the command at the start (``present``, A).
        self._base = (present if cfg.relative and present is not None
                      and cfg.signal != 'staircase' else None)
        rng = np.random.default_rng(cfg.seed)
        kind = cfg.signal
        if kind == 'staircase':
            levels = np.linspace(cfg.levels_min, cfg.levels_max, cfg.n_levels)
            seq = [] if cfg.direction == 'both' else list(levels)
            for lev in levels if cfg.direction == 'both' else []:
                # Up first or down first, drawn from the seed: friction hysteresis shows in
                # both directions without a fixed pattern.
                sign = 1.0 if rng.random() < 0.5 else -1.0
                seq += [lev, lev + sign * cfg.amplitude, lev, lev - sign * cfg.amplitude]
            self._stairs = np.array([self._level(v) for v in seq])
            self.duration = len(seq) * cfg.dwell
        elif kind == 'prbs':
            n = cfg.prbs_order
            # Any non-zero register start gives the same m-sequence, shifted: the seed picks it.
            state = rng.integers(0, 2, n)
            if not state.any():
                state[0] = 1
            from scipy.signal import max_len_seq  # scipy.signal takes 0.6 s to import
            bits = max_len_seq(n, state=state)[0].astype(float)
            self._bits = self._level(cfg.offset) + (2.0 * bits - 1.0) * self._amp(
                cfg.amplitude)
            self.duration = bits.size * cfg.bit_time
        elif kind == 'chirp':
            self.duration = cfg.sweep_time
        else:
            self.duration = math.inf

    def _level(self, value: float) -> float:
        """An operating point in the configured unit to an absolute current [A]."""
        if self._base is not None:
            return self._base + self._amp(value)
        if self.cfg.unit == 'A':
            return float(value)
        return self.pump.current(self.pump.Q_max * value / 100.0)

    def _amp(self, value: float) -> float:
        """An amplitude (or a shift) in the configured unit to a current change [A]."""
        if self.cfg.unit == 'A':
            return float(value)
        return self.pump.Q_max * value / 100.0 / self.pump.gain

    def __call__(self, t):
        """Absolute current [A] at ``t`` seconds after the start (scalar or array)."""
        cfg = self.cfg
        t = np.asarray(t, dtype=float)
        if math.isfinite(self.duration):
            t = np.mod(t, self.duration) if cfg.repeat else np.minimum(
                t, self.duration * (1.0 - 1e-12))
        t = np.maximum(t, 0.0)
        kind = cfg.signal
        if kind == 'staircase':
            idx = np.minimum((t / cfg.dwell).astype(int), self._stairs.size - 1)
            out = self._stairs[idx]
        elif kind == 'prbs':
            idx = np.minimum((t / cfg.bit_time).astype(int), self._bits.size - 1)
            out = self._bits[idx]
        else:
            if kind == 'chirp':
                f0, f1, T = cfg.f_start, cfg.f_end, cfg.sweep_time
                if cfg.sweep == 'logarithmic' and f1 != f0:
                    k = math.log(f1 / f0)
                    phase = 2.0 * math.pi * f0 * T / k * (np.exp(k * t / T) - 1.0)
                else:
                    phase = 2.0 * math.pi * (f0 * t + 0.5 * (f1 - f0) * t * t / T)
            else:
                phase = 2.0 * math.pi * cfg.frequency * t
            out = self._level(cfg.offset) + self._amp(cfg.amplitude) * np.sin(phase)
        return float(out) if np.ndim(out) == 0 else out
