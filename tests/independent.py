"""A pump this code did not make: the truth of the calibration and identification tests.

The plant's equations (``hydropump_sim.model.rhs``, the paper's fine model) are integrated
here by another method than the suite's: scipy's Radau at ``rtol = 1e-9``, one call per
interval of constant inputs, with its dense output. Nothing of ``simulate``, its Rodas4
stepper, its input tables or its sensor models is used. On top of the plant:

- its own sensor chain: an exact transport delay (the dense output evaluated at
  ``t - delay``, off the sample grid if wanted), white noise from its own generator,
  quantisation, and dropped messages (a message that never reached the bag);
- effects the calibrated model leaves fixed, set in the truth's parameters: solenoid lag
  ``input.tau_s``, Coulomb friction, actuator leakage.

A commanded current is logged as held from its sample; a measured signal is sampled, so an
input change at ``t_k`` shows in it from the sample after (the inputs just before ``t_k``).

The inputs are held from sample instants (a digital driver's commands, steps on the grid), and
the bags are written as the recorder writes them (``hydropump_ctrl.bag``), pressures
absolute. Test data only.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.integrate import solve_ivp

from hydropump_ctrl.bag import write_bag
from hydropump_sim.model import outputs, pack, rhs
from hydropump_sim.trim import equilibrium

FLOAT64 = 'std_msgs/msg/Float64'
PRESSURE = 'sensor_msgs/msg/FluidPressure'
JOINTS = 'sensor_msgs/msg/JointState'
# Signal -> (model output, topic, message type); load_pressure is the input P_u.
SIGNALS = {
    'solenoid_current': ('I_s', 'solenoid_current', FLOAT64),
    'line_flow': ('q_l', 'line_flow', FLOAT64),
    'pump_flow': ('Q_p', 'pump_flow', FLOAT64),
    'load_flow': ('Q_load', 'load_flow', FLOAT64),
    'line_pressure': ('P_l', 'line_pressure', PRESSURE),
    'actuator_pressure': ('P_a', 'actuator_pressure', PRESSURE),
    'load_pressure': (None, 'load_pressure', PRESSURE),
}


@dataclass(frozen=True)
class Sensor:
    """A sensor of the bench: delay [s], noise standard deviation and quantum (SI), and the
    probability that a message is dropped."""

    delay: float = 0.0
    noise: float = 0.0
    quantum: float = 0.0
    drop: float = 0.0


# The bench of the tests: a flow meter with a 12.4 ms delay (off the 1 kHz grid), 0.5 % FS
# noise and a 0.25 % FS quantum; pressure transducers of 0.2 bar noise and a 0.1 bar quantum.
FS = 1.125e-3
BENCH = {
    'line_flow': Sensor(0.0124, 0.005 * FS, 0.0025 * FS),
    'line_pressure': Sensor(0.0, 2.0e4, 1.0e4),
    'actuator_pressure': Sensor(0.0, 2.0e4, 1.0e4),
    'load_pressure': Sensor(0.0, 2.0e4, 1.0e4),
    'solenoid_current': Sensor(0.0, 0.0, 4.0e-4),
}


@dataclass
class Run:
    """One experiment on the true plant: piecewise-constant inputs and the dense solution."""

    params: object
    dt: float
    current: np.ndarray          # absolute A, held from sample k
    load_pressure: np.ndarray    # gauge Pa, held from sample k
    pieces: list = field(default_factory=list)   # (t0, t1, u, dense solution)
    x0: np.ndarray | None = None

    @property
    def n(self) -> int:
        return self.current.size

    def state(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """The state and the held inputs at time ``t`` (before 0: the initial rest)."""
        if t <= 0.0:
            return self.x0, self.pieces[0][2]
        starts = [p[0] for p in self.pieces]
        k = int(np.searchsorted(starts, t, side='right') - 1)
        t0, t1, u, sol = self.pieces[min(k, len(self.pieces) - 1)]
        return sol(min(t, t1)), u

    def signal(self, name: str, times: np.ndarray) -> np.ndarray:
        """The true signal at ``times`` [s] (SI, gauge)."""
        out_name = SIGNALS[name][0]
        p = pack(self.params)
        vals = np.empty(times.size)
        for i, t in enumerate(times):
            # A sampler sees an input change at the sample after it: the inputs are those
            # just before ``t`` (the state is continuous).
            x, u = self.state(float(t))
            u = self.state(float(t) - 1e-9)[1]
            if out_name is None:
                vals[i] = u[1]
            else:
                vals[i] = outputs(max(float(t), 0.0), x, u, self.params, p=p)[out_name]
        return vals


def run(params, current: np.ndarray, load_pressure: np.ndarray | None = None,
        dt: float = 1e-3, rtol: float = 1e-9) -> Run:
    """Integrate the true plant over the held inputs (see the module)."""
    current = np.asarray(current, float)
    load = (np.full(current.size, params.line.P_u) if load_pressure is None
            else np.asarray(load_pressure, float))
    x0 = equilibrium(params, float(current[0]), load_pressure=float(load[0])).x
    p = pack(params)
    r = Run(params, dt, current, load, x0=x0)
    change = np.flatnonzero((np.diff(current) != 0) | (np.diff(load) != 0)) + 1
    edges = [0, *change.tolist(), current.size]
    x = x0.copy()
    scale = np.array([params.spool.x_c_max, 0.1, params.x_a_stop, 0.1, 1e6, 1e6, 0.4][:x.size])
    for a, b in zip(edges[:-1], edges[1:]):
        u = np.array([current[a], load[a], params.line.xi_u,
                      params.pump.f_p])
        t0, t1 = a * dt, b * dt
        sol = solve_ivp(rhs, (t0, t1), x, method='Radau', args=(u, params, 'fine', None, p),
                        rtol=rtol, atol=rtol * scale, dense_output=True, first_step=1e-6)
        assert sol.success, sol.message
        r.pieces.append((t0, t1, u, sol.sol))
        x = sol.y[:, -1].copy()
    return r


def sample(r: Run, sensors: dict[str, Sensor]) -> dict[str, np.ndarray]:
    """Every signal of ``sensors`` on the grid ``k dt`` after its sensor's delay, before
    noise (SI, gauge): what :func:`noisy` adds the bench's noise to."""
    t = np.arange(r.n) * r.dt
    return {name: r.current.copy() if name == 'solenoid_current'
            else r.signal(name, t - s.delay) for name, s in sensors.items()}


def noisy(clean: dict[str, np.ndarray], sensors: dict[str, Sensor], seed
          ) -> dict[str, np.ndarray]:
    """The bench's records of ``clean`` signals: noise from a generator seeded ``seed``,
    quantisation, dropped messages (NaN). ``seed`` is an int or a tuple of ints."""
    rng = np.random.default_rng(seed)
    out = {}
    for name, s in sensors.items():
        y = clean[name].copy()
        if s.noise:
            y = y + rng.normal(0.0, s.noise, y.size)
        if s.quantum:
            y = s.quantum * np.round(y / s.quantum)
        if s.drop:
            y[1:][rng.random(y.size - 1) < s.drop] = np.nan
        out[name] = y
    return out


def measure(r: Run, sensors: dict[str, Sensor], seed: int) -> dict[str, np.ndarray]:
    """Every signal of ``sensors`` as the bench records it on the grid ``k dt`` (SI, gauge;
    NaN where a message was dropped)."""
    return noisy(sample(r, sensors), sensors, seed)


def write(path: Path, dt: float, signals: dict[str, np.ndarray], p_atm: float,
          t0: float = 1.0) -> Path:
    """The signals as a rosbag2 bag with the suite's topics (pressures absolute; a dropped
    sample is a message that is not there), stamped from ``t0`` [s]."""
    streams = {}
    for name, y in signals.items():
        _, topic, msgtype = SIGNALS[name]
        ok = np.isfinite(y)
        t = t0 + np.arange(y.size) * dt
        v = y + (p_atm if msgtype == PRESSURE else 0.0)
        streams[f'/{topic}'] = (msgtype, t[ok], v[ok])
    return write_bag(path, streams)


def staircase(levels, dwell: float, dt: float = 1e-3) -> np.ndarray:
    """Held levels, ``dwell`` seconds each."""
    return np.repeat(np.asarray(levels, float), int(round(dwell / dt)))


