"""Physical invariants of a circuit's run, checked over the whole run, not trusted.

- **No pressure above what a source can make.** Every node stays at or below the highest
  pressure any component of the circuit could produce with the inputs it held so far (a
  relief's full-flow pressure plus one regulation range, a pump's cut-off and its band, a
  held source, a load's force over its area: :meth:`Component.pressure_cap
  <hydropump_sim.components.base.Component.pressure_cap>`), plus :data:`CAP_MARGIN`.
- **None below the cavitation floor**: absolute zero, less what the floor's relaxation lets a
  step overshoot (:data:`FLOOR_MARGIN`).
- **No component makes energy**: every passive component's dissipated power (its ``loss``
  signal) is at least zero (:data:`LOSS_MARGIN`).
- **Energy balanced**: at every instant, the power supplied equals what the loads take, what
  is stored and what is dissipated (:mod:`.energy`'s ``power:balance``), to rounding.
- **Every value finite.**

A circuit whose pump nothing limits (no relief valve, no cut-off) is refused by the compiler
before any run. :func:`check` returns one
:class:`Violation` per invariant and place that fails, with the time and the value of its
worst sample; :func:`report` words them, one line each.
"""

from __future__ import annotations

from dataclasses import dataclass
import math

import numpy as np

from .energy import balance_bound, POWER_PREFIX
from .errors import HydropumpError

#: Allowed excess over the highest source pressure: 2 % and 1 bar (a step's overshoot of a
#: relief's regulation, the numerics of a stiff node).
CAP_MARGIN = (0.02, 1.0e5)
#: How far below absolute zero a node may dip [Pa] (the floor relaxes it back in 0.1 ms).
FLOOR_MARGIN = 1.0e4
#: The most negative dissipated power a passive component may show [W] (rounding).
LOSS_MARGIN = 1.0e-6


@dataclass(frozen=True)
class Violation:
    """One invariant that fails: what, where (a node or a component), when and how far."""

    invariant: str
    where: str
    t: float
    value: float
    bound: float
    unit: str

    def __str__(self) -> str:
        scale, unit = (1.0e-5, 'bar') if self.unit == 'Pa' else (1.0, self.unit)
        return (f'{self.invariant}: {self.where} at t = {self.t:.6g} s: '
                f'{self.value * scale:.6g} {unit} (bound {self.bound * scale:.6g} {unit})')


def check(model, t: np.ndarray, y: np.ndarray, u: np.ndarray) -> list[Violation]:
    """Every invariant over a run of ``model``: times ``t`` [s], signals ``y`` (rows of
    ``model.signals``), held inputs ``u`` (rows of ``model.inputs``)."""
    out: list[Violation] = []
    t = np.asarray(t, dtype=float)
    bad = ~np.isfinite(y)
    if bad.any():
        k, j = np.argwhere(bad)[0]
        out.append(Violation('a value that is not finite', model.signals[j], float(t[k]),
                             float(y[k, j]), math.inf, model.signal_units[j]))
        return out
    # What a source made at any earlier time can stay stored (a charged accumulator, a
    # trapped volume): the cap is the highest so far.
    cap = np.fmax.accumulate(model.pressure_caps(u))
    limit = cap * (1.0 + CAP_MARGIN[0]) + CAP_MARGIN[1]
    p_atm = model.fluid.p_atm
    floor = -p_atm - FLOOR_MARGIN
    for node, signal in model.pressure_nodes():
        P = y[:, model.signal_index(signal)]
        over = P - limit
        if np.any(over > 0.0):
            k = int(np.nanargmax(over))
            out.append(Violation('a pressure above every source', f'node {node}',
                                 float(t[k]), float(P[k]), float(cap[k]), 'Pa'))
        if np.any(P < floor):
            k = int(np.argmin(P))
            out.append(Violation('a pressure below the cavitation floor', f'node {node}',
                                 float(t[k]), float(P[k]), -p_atm, 'Pa'))
    if f'{POWER_PREFIX}balance' in model.signals:
        bal = y[:, model.signal_index(f'{POWER_PREFIX}balance')]
        bound = balance_bound(y, model.signal_index)
        if np.any(np.abs(bal) > bound):
            k = int(np.argmax(np.abs(bal) / bound))
            out.append(Violation('energy not balanced', 'the circuit', float(t[k]),
                                 float(bal[k]), float(bound[k]), 'W'))
    for j, name in enumerate(model.signals):
        if name.endswith('.loss') and np.any(y[:, j] < -LOSS_MARGIN):
            k = int(np.argmin(y[:, j]))
            out.append(Violation('a component making energy', name[:-len('.loss')],
                                 float(t[k]), float(y[k, j]), 0.0, 'W'))
    return out


class InvariantError(HydropumpError, RuntimeError):
    """A run broke a physical invariant (raised where they are enforced)."""

    head = 'a physical invariant broken'

    def __init__(self, violations, source: str | None = None):
        self.violations = list(violations)
        super().__init__([str(v) for v in self.violations], source)


def strict() -> bool:
    """Whether runs raise on a broken invariant (``HYDROPUMP_STRICT_INVARIANTS=1``, as the
    test suite sets it): every offline run then proves them."""
    import os
    return os.environ.get('HYDROPUMP_STRICT_INVARIANTS', '') not in ('', '0')


def report(violations: list[Violation]) -> str:
    """One line per violation, or a line saying that every invariant held."""
    if not violations:
        return 'invariants: every one held over the whole run'
    return '\n'.join(f'invariant broken: {v}' for v in violations)
