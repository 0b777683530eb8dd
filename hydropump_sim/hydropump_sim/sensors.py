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
import dataclasses
from dataclasses import dataclass, fields
import math
from pathlib import Path
from typing import Any

import numpy as np

from .measure import SIGNALS as MEASURED
from .schema import (
    build,
    check_all,
    group,
    ParamError,
    ParamSpec,
    read_params_file,
    spec,
    specs_of,
    to_flat,
)

# Measured signals and their SI units (the one table is hydropump_sim.measure.SIGNALS).
SIGNALS = {name: info.unit for name, info in MEASURED.items()}

# Largest noise and quantum per unit: beyond these a value was typed in another unit.
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


def _sensor_class(unit: str) -> type:
    """The schema of one signal's sensor, its noise and quantum in the signal's ``unit``."""
    top = _SCALE_MAX[unit]
    cls = dataclasses.make_dataclass(f'Sensor_{unit}', [
        ('delay', float, spec('s', 'transport/measurement delay', 0.0, 2.0, default=0.0)),
        ('noise_std', float, spec(unit, 'white noise std', 0.0, top, default=0.0)),
        ('quantum', float, spec(unit, 'quantisation step', 0.0, top, default=0.0)),
        ('filter_tau', float, spec('s', 'first-order filter time constant', 0.0, 10.0,
                                   default=0.0)),
    ], bases=(SensorSpec,), frozen=True)
    cls.__module__ = __name__
    return cls


_SENSOR_CLASSES = {unit: _sensor_class(unit) for unit in _SCALE_MAX}

# Group ``sensors``: one sensor per measured signal, and the noise seed.
Sensors = dataclasses.make_dataclass('Sensors', [
    (sig, _SENSOR_CLASSES[unit], group(factory=_SENSOR_CLASSES[unit]))
    for sig, unit in SIGNALS.items()] + [
    ('seed', int, spec('-', 'seed of the sensor noise (one stream per signal; live: from '
                       'the next ~/reset on)', 0, 2 ** 31 - 1, default=0, live=True)),
], frozen=True)
Sensors.__module__ = __name__
Sensors.__doc__ = 'Group ``sensors``: the sensor model of every measured signal and the seed.'


@dataclass(frozen=True)
class SensorConfig:
    """The ``sensors`` group of a node's parameters (its schema root)."""

    sensors: Sensors = group(factory=Sensors)


@dataclass(frozen=True)
class SensorProfile:
    """Sensor models of every signal, the noise seed and plant overrides of the profile."""

    sensors: dict
    seed: int = 0
    plant_overrides: dict | None = None

    def spec(self, signal: str) -> SensorSpec:
        return self.sensors.get(signal, SensorSpec())

    def flat(self) -> dict[str, Any]:
        """The ``sensors.*`` parameters of this profile (ROS names), every signal listed."""
        return to_flat(_config(self))

    @classmethod
    def from_config(cls, cfg: SensorConfig, plant_overrides: dict | None = None
                    ) -> SensorProfile:
        """The profile of a validated ``sensors`` group (e.g. declared node parameters)."""
        specs = {sig: SensorSpec(**dataclasses.asdict(getattr(cfg.sensors, sig)))
                 for sig in SIGNALS}
        return cls({s: sp for s, sp in specs.items() if sp.active}, cfg.sensors.seed,
                   plant_overrides or None)


def _config(profile: SensorProfile) -> SensorConfig:
    kw = {sig: _SENSOR_CLASSES[unit](**dataclasses.asdict(profile.spec(sig)))
          for sig, unit in SIGNALS.items()}
    return SensorConfig(Sensors(**kw, seed=profile.seed))


def sensor_specs() -> tuple[ParamSpec, ...]:
    """Schema of the ``sensors`` group (ROS parameter names, ranges, defaults)."""
    return specs_of(SensorConfig)


def profile_from_dict(data: Mapping[str, Any], source: str | None = None) -> SensorProfile:
    """Validate a ``{sensors: {...}, <plant group>: {...}}`` mapping into a profile.

    Entries outside ``sensors`` are plant parameters the profile overrides (the bench's
    dither); they are checked against the plant schema where the profile is applied.
    """
    sensors = {k: v for k, v in data.items() if k == 'sensors' or k.startswith('sensors.')}
    if 'sensors' in sensors and not isinstance(sensors['sensors'], Mapping):
        raise ParamError(['sensors: expected a mapping of signals'], source)
    cfg = build(SensorConfig, sensors, source, what='sensor parameter')
    overrides = {}
    for key, val in data.items():
        if key in sensors:
            continue
        if isinstance(val, Mapping):
            overrides.update({f'{key}.{k}': v for k, v in val.items()})
        else:
            overrides[key] = val
    return SensorProfile.from_config(cfg, overrides)


def check_profile_values(flat: Mapping[str, Any]) -> list[str]:
    """One line per bad ``sensors.*`` value of a flat mapping (node parameters)."""
    return check_all(SensorConfig, {k: v for k, v in flat.items() if k.startswith('sensors.')},
                     what='sensor parameter')[1]


def load_profile(path: str | Path) -> SensorProfile:
    """Load a sensor profile file such as ``config/bench.yaml``."""
    return profile_from_dict(read_params_file(path), str(path))


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
    """One :class:`SensorChannel` per signal of a profile, sharing one seeded generator.

    ``like`` adds signals the profile does not name, each measured by a sensor of the kind
    of a named one (a circuit's load-sensing pressure by a transducer like the line
    pressure's), with noise of its own.
    """

    def __init__(self, profile: SensorProfile, dt: float, like: dict[str, str] | None = None):
        self.profile = profile
        self.dt = dt
        self.like = dict(like or {})
        self.reset()

    def reset(self) -> None:
        # One generator per signal keeps a signal's noise independent of which others are on.
        self.channels = {sig: SensorChannel(self.profile.spec(sig), self.dt,
                                            np.random.default_rng([self.profile.seed, i]))
                         for i, sig in enumerate(SIGNALS)}
        for i, (sig, kind) in enumerate(self.like.items(), len(SIGNALS)):
            self.channels[sig] = SensorChannel(self.profile.spec(kind), self.dt,
                                               np.random.default_rng([self.profile.seed, i]))

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
