"""Sensor models and sensor profiles (delay, white noise, quantisation, first-order filter).

A profile file is a ROS 2 params file for the simulator node. Its ``sensors`` group gives, per
measured signal, ``delay`` [s], ``noise_std`` and ``quantum`` (in the signal's SI unit) and
``filter_tau`` [s], plus ``sensors.seed``; all are off (zero) by default. Other groups override
plant parameters (for example ``input.dither_amp``). ``config/bench.yaml`` reproduces the
paper's test bench: 55 ms on the current-to-flow measurement path, noise, quantisation, dither.

The chain per signal is: first-order filter, transport delay (fractional, by linear
interpolation between samples), white Gaussian noise, quantisation.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass, fields
import math
from pathlib import Path
from typing import Any

import numpy as np

from .params import check_value, ParamError, ParamSpec, read_yaml, ros_parameters

# Measured signals and their SI units.
SIGNALS = {
    'solenoid_current': 'A',
    'pump_flow': 'm^3/s',
    'line_flow': 'm^3/s',
    'load_flow': 'm^3/s',
    'actuator_pressure': 'Pa',
    'line_pressure': 'Pa',
    'load_pressure': 'Pa',
    'spool_position': 'm',
    'actuator_position': 'm',
}

# Accepted ranges per field: delay and filter in s; noise and quantum relative to the unit.
_FIELD_RANGES = {'delay': (0.0, 2.0), 'filter_tau': (0.0, 10.0)}
_SCALE_MAX = {'A': 1.0, 'm^3/s': 1.0e-2, 'Pa': 1.0e7, 'm': 1.0e-2}


@dataclass(frozen=True)
class SensorSpec:
    """Sensor model of one signal; zeros switch each part off."""

    delay: float = 0.0
    noise_std: float = 0.0
    quantum: float = 0.0
    filter_tau: float = 0.0

    @property
    def active(self) -> bool:
        return any(getattr(self, f.name) > 0.0 for f in fields(self))


@dataclass(frozen=True)
class SensorProfile:
    """Sensor models of every signal, the noise seed and plant overrides of the profile."""

    sensors: dict
    seed: int = 0
    plant_overrides: dict | None = None

    def spec(self, signal: str) -> SensorSpec:
        return self.sensors.get(signal, SensorSpec())


def sensor_specs() -> list[ParamSpec]:
    """Schema of the ``sensors`` group (ROS parameter names and ranges)."""
    out = []
    for sig, unit in SIGNALS.items():
        for f in fields(SensorSpec):
            if f.name in _FIELD_RANGES:
                u, rng = 's', _FIELD_RANGES[f.name]
            else:
                u, rng = unit, (0.0, _SCALE_MAX[unit])
            desc = {'delay': 'transport/measurement delay', 'noise_std': 'white noise std',
                    'quantum': 'quantisation step', 'filter_tau': 'first-order filter'}[f.name]
            out.append(ParamSpec(f'sensors.{sig}.{f.name}', float, u, f'{desc} of {sig}', rng,
                                 None, True, False))
    return out


def profile_from_dict(data: Mapping[str, Any], source: str | None = None) -> SensorProfile:
    """Validate a ``{sensors: {...}, <plant group>: {...}}`` mapping into a profile."""
    errors: list[str] = []
    specs = {s.name: s for s in sensor_specs()}
    sensors_raw = data.get('sensors', {}) or {}
    seed = 0
    per_signal: dict[str, dict] = {}
    if not isinstance(sensors_raw, Mapping):
        raise ParamError(['sensors: expected a mapping'], source)
    for sig, val in sensors_raw.items():
        if sig == 'seed':
            if isinstance(val, bool) or not isinstance(val, int) or val < 0:
                errors.append(f'sensors.seed = {val!r}: expected a non-negative integer')
            else:
                seed = val
            continue
        if sig not in SIGNALS or not isinstance(val, Mapping):
            errors.append(f'sensors.{sig}: unknown signal (use {", ".join(SIGNALS)})')
            continue
        for key, v in val.items():
            s = specs.get(f'sensors.{sig}.{key}')
            if s is None:
                errors.append(f'sensors.{sig}.{key}: unknown (use delay, noise_std, quantum, '
                              'filter_tau)')
                continue
            v, err = check_value(s, v)
            if err:
                errors.append(err)
            else:
                per_signal.setdefault(sig, {})[key] = v
    if errors:
        raise ParamError(errors, source)
    overrides = {f'{g}.{k}': v for g, grp in data.items() if g != 'sensors'
                 and isinstance(grp, Mapping) for k, v in grp.items()}
    return SensorProfile({s: SensorSpec(**kw) for s, kw in per_signal.items()}, seed,
                         overrides or None)


def load_profile(path: str | Path) -> SensorProfile:
    """Load a sensor profile file such as ``config/bench.yaml``."""
    doc = ros_parameters(read_yaml(path))
    return profile_from_dict(doc if isinstance(doc, Mapping) else {}, str(path))


class SensorChannel:
    """Sampled sensor model of one signal at a fixed period ``dt``.

    Feed the true value every period with :meth:`update`; it returns the measurement.
    """

    def __init__(self, spec: SensorSpec, dt: float, rng: np.random.Generator):
        self.spec = spec
        self.dt = dt
        self.rng = rng
        steps = spec.delay / dt
        self._n = int(math.floor(steps))
        self._frac = steps - self._n
        self._buf: deque = deque(maxlen=self._n + 2)
        self._y = None
        self._alpha = (1.0 - math.exp(-dt / spec.filter_tau)) if spec.filter_tau > 0 else 1.0

    def reset(self) -> None:
        self._buf.clear()
        self._y = None

    def update(self, value: float) -> float:
        """Measurement of this period for the true ``value``."""
        s = self.spec
        self._y = value if self._y is None else self._y + self._alpha * (value - self._y)
        if not self._buf:
            # Start from a steady history, as the plant starts from equilibrium.
            self._buf.extend([self._y] * (self._n + 2))
        self._buf.append(self._y)
        # buf[-1] is now, buf[-1 - n] is n periods ago.
        a = self._buf[-1 - self._n]
        b = self._buf[-2 - self._n]
        y = a + self._frac * (b - a)
        if s.noise_std > 0.0:
            y += self.rng.normal(0.0, s.noise_std)
        if s.quantum > 0.0:
            y = s.quantum * round(y / s.quantum)
        return y


class SensorBank:
    """One :class:`SensorChannel` per signal of a profile, sharing one seeded generator."""

    def __init__(self, profile: SensorProfile, dt: float):
        self.profile = profile
        self.dt = dt
        self.reset()

    def reset(self) -> None:
        # One generator per signal keeps a signal's noise independent of which others are on.
        self.channels = {sig: SensorChannel(self.profile.spec(sig), self.dt,
                                            np.random.default_rng([self.profile.seed, i]))
                         for i, sig in enumerate(SIGNALS)}

    def measure(self, true_values: Mapping[str, float]) -> dict[str, float]:
        """Measurements of this period for the given true values (SI)."""
        return {sig: self.channels[sig].update(v) for sig, v in true_values.items()}


def apply_profile(profile: SensorProfile, t: np.ndarray, signals: Mapping[str, np.ndarray]
                  ) -> dict[str, np.ndarray]:
    """Offline version of :class:`SensorBank` for uniformly sampled arrays (same results)."""
    dt = float(t[1] - t[0])
    bank = SensorBank(profile, dt)
    out = {k: np.empty(len(v)) for k, v in signals.items()}
    for k in range(len(t)):
        meas = bank.measure({name: float(v[k]) for name, v in signals.items()})
        for name, val in meas.items():
            out[name][k] = val
    return out
