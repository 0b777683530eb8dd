"""The energy account of a circuit: where the pump's power goes.

Every component reports the power its ports take, ``sum P_port Q_into_it``, split into what it
dissipates (``loss``), delivers to the world outside (``work``: a load force times its
velocity), stores (``stored``: kinetic energy, springs, gas, its own volumes) and gives
(``supply``: a pump) (components/base.py, ``ENERGY_TERMS``). Each node takes ``P Q_net``,
the power that compresses its oil; a node whose pressure is held (a tank, a source) gives
``-P Q_net``. The circuit sums them into its ``power:*`` signals [W]:

- ``power:supply``: the pumps', and what held pressures give;
- ``power:work``: what the loads take;
- ``power:stored``: the components' stored power and the nodes' compression;
- ``power:loss`` and ``power:loss.<group>`` (``LOSS_GROUPS``: compensators, relief, lines...);
- ``power:balance = supply - work - stored - loss``, zero to rounding at every instant if
  every component accounts for the flows it makes: a flow no term carries, a loss computed
  on another pressure than the one the flow crosses, shows here. :mod:`.invariants` checks
  it over every run.

:func:`account` integrates them over a run: energies [J] by term and loss group.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Prefix of the circuit's power signals.
POWER_PREFIX = 'power:'
#: The balance may differ from zero by this fraction of the largest term at that instant
#: (rounding: a node's ``P Q_net`` is the difference of flows some 1e-16 apart).
BALANCE_TOL = 1.0e-9
#: ... and by this much [W] (a circuit at rest).
BALANCE_FLOOR = 1.0e-6
TERMS = ('supply', 'work', 'stored', 'loss')


@dataclass(frozen=True)
class PowerSignals:
    """Which signals and nodes make each power signal of a circuit (indices only)."""

    terms: dict[str, list[int]]        # term -> component signal indices
    groups: dict[str, list[int]]       # loss group -> component signal indices
    free_nodes: list[int]              # node indices whose P Q_net is stored
    fixed_nodes: list[int]             # node indices whose -P Q_net is supplied

    def names(self) -> list[str]:
        return ([f'{POWER_PREFIX}{t}' for t in TERMS]
                + [f'{POWER_PREFIX}loss.{g}' for g in self.groups]
                + [f'{POWER_PREFIX}balance'])


def power_signals(parts, nodes: list[str], fixed) -> PowerSignals:
    """The power signals of a circuit's ``parts`` (their components' ``ENERGY_TERMS``
    signals, each loss under its ``LOSS_GROUP``)."""
    from .components.base import LOSS_GROUPS
    terms: dict[str, list[int]] = {t: [] for t in TERMS}
    groups: dict[str, list[int]] = {}
    for part in parts:
        names = [s.name for s in part.comp.SIGNALS]
        for t in TERMS:
            if t in names:
                terms[t].append(part.y.start + names.index(t))
        if 'loss' in names:
            group = part.comp.LOSS_GROUP
            if group not in LOSS_GROUPS:
                raise ValueError(f'{type(part.comp).__name__}: its loss has no group of '
                                 f'{sorted(LOSS_GROUPS)}')
            groups.setdefault(group, []).append(part.y.start + names.index('loss'))
    order = {g: k for k, g in enumerate(LOSS_GROUPS)}
    groups = dict(sorted(groups.items(), key=lambda kv: order[kv[0]]))
    return PowerSignals(terms, groups,
                        [i for i, n in enumerate(nodes) if n not in fixed],
                        [i for i, n in enumerate(nodes) if n in fixed])


def code(ps: PowerSignals, y0: int, table) -> list[str]:
    """The generated lines that set the power signals from ``y[y0]`` on (after every
    kernel, with the nodes' net flows ``Q`` complete): a loop over an index table per
    signal (``table(values)`` names a module-level table of the generated source), so that
    the source grows with the number of terms, not of components."""
    out = []
    k = y0
    slot = {}

    def total(idx, nodes=(), sign='+'):
        nonlocal k
        out.extend(['    s = 0.0', f'    for i in {table(idx)}:', '        s += y[i]'])
        if nodes:  # each node's compression power, stored (free) or given (held)
            out.extend([f'    for i in {table(nodes)}:', f'        s {sign}= P[i] * Q[i]'])
        out.append(f'    y[{k}] = s')
        k += 1
        return k - 1

    nodes = {'supply': (ps.fixed_nodes, '-'), 'stored': (ps.free_nodes, '+')}
    for t in TERMS:
        slot[t] = total(ps.terms[t], *nodes.get(t, ((), '+')))
    for idx in ps.groups.values():
        total(idx)
    out.append(f'    y[{k}] = y[{slot["supply"]}] - y[{slot["work"]}] - y[{slot["stored"]}]'
               f' - y[{slot["loss"]}]')
    return out


def balance_bound(y: np.ndarray, index) -> np.ndarray:
    """The largest balance allowed at each sample of a run (rows of signals ``y``)."""
    big = np.max(np.abs(np.stack([y[:, index(f'{POWER_PREFIX}{t}')] for t in TERMS])),
                 axis=0)
    return BALANCE_TOL * big + BALANCE_FLOOR


@dataclass
class Account:
    """Energies [J] over a run: each term, and the losses by group."""

    supply: float
    work: float
    stored: float
    loss: float
    groups: dict[str, float]

    @property
    def balance(self) -> float:
        """What is unaccounted for [J]."""
        return self.supply - self.work - self.stored - self.loss

    @property
    def relative(self) -> float:
        """The balance over the energy supplied."""
        return abs(self.balance) / max(abs(self.supply), 1.0e-300)


def account(result, t0: float | None = None, t1: float | None = None) -> Account:
    """The energy account of a circuit's run (a :class:`~hydropump_sim.system.Result`),
    its power signals integrated by the trapezoidal rule, from ``t0`` to ``t1`` [s]."""
    t = np.asarray(result.t, dtype=float)
    keep = np.ones(t.shape, dtype=bool)
    if t0 is not None:
        keep &= t >= t0
    if t1 is not None:
        keep &= t <= t1
    t = t[keep]

    def energy(name):
        return float(np.trapezoid(result[f'{POWER_PREFIX}{name}'][keep], t))
    groups = {s[len(POWER_PREFIX) + 5:]: energy(s[len(POWER_PREFIX):])
              for s in result.model.signals if s.startswith(f'{POWER_PREFIX}loss.')}
    return Account(*(energy(name) for name in TERMS), groups)


#: How often a simulator publishes its energies [s of simulation]: cumulative values,
#: which a reader needs no faster (the publishing rate still integrates them).
PUBLISH_PERIOD = 0.01


def topics(model) -> list[tuple[str, str]]:
    """``(topic, power signal)`` of the energies a simulator publishes for ``model``:
    ``energy/supply``, ``energy/work``, ``energy/stored``, ``energy/loss`` and
    ``energy/loss/<group>`` (none for a model without the account)."""
    if f'{POWER_PREFIX}balance' not in model.signals:
        return []
    out = [(f'energy/{t}', f'{POWER_PREFIX}{t}') for t in TERMS]
    out += [(f'energy/loss/{s[len(POWER_PREFIX) + 5:]}', s) for s in model.signals
            if s.startswith(f'{POWER_PREFIX}loss.')]
    return out


def cumulative(model, t: np.ndarray, y: np.ndarray) -> dict[str, np.ndarray]:
    """The energies of a whole run so far at each sample [J] by :func:`topics` name: what a
    :class:`Meter` fed every sample gives (rows of signals ``y`` at times ``t``)."""
    from scipy.integrate import cumulative_trapezoid
    return {topic: cumulative_trapezoid(y[:, model.signal_index(signal)], t, initial=0.0)
            for topic, signal in topics(model)}


class Meter:
    """The energies of a run so far [J], its power signals integrated by the trapezoidal
    rule at each sample :meth:`add` is given (a simulator's published steps)."""

    def __init__(self, model):
        pairs = topics(model)
        self.names = [p[0] for p in pairs]
        self._index = np.array([model.signal_index(p[1]) for p in pairs], dtype=np.int64)
        self.reset()

    def reset(self) -> None:
        self._t = None
        self._last = None
        self.total = np.zeros(len(self.names))

    def add(self, t: float, y: np.ndarray) -> None:
        now = y[self._index]
        if self._t is not None and t > self._t:
            self.total += 0.5 * (now + self._last) * (t - self._t)
        self._t, self._last = t, now

    def values(self) -> dict[str, float]:
        return dict(zip(self.names, self.total.tolist()))
