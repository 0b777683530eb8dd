"""The one model interface of the plant library, and the results every model gives.

Two implementations: the paper's pump alone (:class:`hydropump_sim.plant_model.PumpModel`,
the fixed layout of eqs. 1-9 with its fine and simplified forms) and any circuit
(:class:`hydropump_sim.circuit.Circuit`, compiled from a YAML file of components). Whatever
runs a model runs either: one simulation and one stepper (:mod:`hydropump_sim.simulate`),
one steady-state search (:mod:`hydropump_sim.steady`), one linearisation, modal analysis,
transfer matrix and singular-perturbation check (:mod:`hydropump_sim.linear`), the
simulator node's runner, the closed-loop harness and the invariant checker. As
python-control's ``nlsys`` or Drake's ``System``, a model is stateless: it names its states,
inputs and signals with their units, holds its packed parameters ``p``, and gives one
compiled ``evaluate(t, x, u, p, dx, y)`` (:data:`hydropump_sim.integrator.EVALUATE`) with the
structure the stepper needs (state scales, the sparsity of its Jacobian and a colouring).

Signals and inputs are named ``<component>.<name>`` (``pump.q_l``, ``boom.command``); a
result or a steady state is indexed by those names (``res['pump.q_l']``).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
import math
from pathlib import Path
from typing import Any

import numpy as np

from .errors import HydropumpError, InputError
from .files import replacing
from .schema import closest_name, text_number_hint


class ModelError(HydropumpError, ValueError):
    """A name a model does not have, a value outside an input's range."""

    head = 'invalid model use'


def unknown(name: str, names, what: str) -> str:
    close = closest_name(name, names)
    return f'{name}: unknown {what}' + (f' (did you mean {close}?)' if close else '')


class Model:
    """The interface every model implements (see the module).

    Attributes an implementation sets
    ---------------------------------
    name : str
    states, state_units : list of str
    state_scale : ndarray
        Typical magnitude of each state (tolerances, difference steps).
    integrating : ndarray of bool
        States a steady state does not hold still (a cylinder's position).
    state_stops : ndarray (n, 2) or None
        Their end stops (NaN: none), where a steady state holds them still after all.
    inputs, input_units : list of str
    input_ranges : list of (float, float)
    u0 : ndarray
        The inputs it holds unless told otherwise.
    signals, signal_units : list of str
    p : ndarray
        Packed parameters of ``evaluate``.
    dither : float
        Frequency [Hz] of a time dependence within a held increment (0: none).
    fluid : Fluid
        Its fluid (density, bulk modulus, the atmosphere's pressure).

    and the methods :meth:`structure`, :attr:`evaluate_c` and :meth:`start_states`.
    """

    error = ModelError
    state_stops: np.ndarray | None = None

    # ---- names ----------------------------------------------------------------------------

    def _alias(self, name: str, kind: str) -> str:
        """A model's own short names for its signals or inputs (a composite's)."""
        return name

    def signal_index(self, name: str) -> int:
        """Index in ``y`` of a signal."""
        full = self._alias(name, 'signals')
        try:
            return self.signals.index(full)
        except ValueError:
            raise self.error([unknown(name, self.signals, 'signal')]) from None

    def input_index(self, name: str) -> int:
        """Index in ``u`` of an input."""
        full = self._alias(name, 'inputs')
        try:
            return self.inputs.index(full)
        except ValueError:
            raise self.error([unknown(name, self.inputs, 'input')]) from None

    def all_inputs(self) -> list[str]:
        return list(self.inputs)

    def component_signals(self) -> list[str]:
        """Every signal a user reads."""
        return list(self.signals)

    @property
    def n_states(self) -> int:
        return len(self.states)

    @property
    def n_signals(self) -> int:
        return len(self.signals)

    # ---- what the suite reads of it (roles) -----------------------------------------------

    def measured(self) -> dict[str, str]:
        """The suite's measured signals (``hydropump_sim.measure.SIGNALS`` names, and
        ``ls_pressure``) -> the model's signal each is."""
        return {}

    def loads(self) -> dict[str, dict[str, str]]:
        """The loads it publishes beside the pump's signals: name -> their signals and
        command input."""
        return {}

    def own_topics(self) -> list:
        """Topics of its own besides the loads' (:class:`~hydropump_sim.measure.Topic`: a
        user's FMU publishes every output)."""
        return []

    def joints(self) -> list[tuple[str, str | None, str | None]]:
        """``(joint, position signal, velocity signal)`` of its ``joint_states`` entries
        besides the pump's spool and swash plate."""
        return []

    def electric_pump(self) -> bool:
        """Whether its pump is driven by the solenoid current ``<pump>.current``."""
        return False

    def pump_name(self) -> str | None:
        """The name of its pump component (the prefix of its pump signals)."""
        return None

    def plant_inputs(self) -> dict[str, str]:
        """The operating point's inputs it has (``current``, ``load_pressure``,
        ``aperture``, ``shaft_speed``: the simulator's parameters) -> its input names."""
        return {}

    def operator_inputs(self) -> list[str]:
        """The inputs an operator or a duty cycle sets (none for the pump alone)."""
        return []

    def main_inputs(self) -> list[str]:
        """The pump's current and every load's command: what drives it."""
        names = [v['command'] for v in self.loads().values() if 'command' in v]
        if self.electric_pump():
            names.insert(0, f'{self.pump_name()}.current')
        return names

    def judged_signals(self) -> list[str]:
        """Line and load-sensing pressures and every load's flow: what a controller and
        an operator judge it by."""
        m = self.measured()
        out = [m[k] for k in ('line_pressure', 'ls_pressure') if k in m]
        out += [v['flow'] for v in self.loads().values() if 'flow' in v]
        return out

    def relieved(self) -> list[str]:
        """The flow signals of what limits its pressure (relief valves)."""
        return []

    def pressure_nodes(self) -> list[tuple[str, str]]:
        """Its hydraulic nodes and the signal of each one's pressure (the invariants)."""
        return []

    def pressure_caps(self, U: np.ndarray) -> np.ndarray:
        """The highest pressure [Pa] any of its sources can make at each row of held
        inputs ``U`` (``nan``: none limits it)."""
        return np.full(U.shape[0], np.nan)

    def branch_p(self, branch: str | None) -> np.ndarray:
        """The packed parameters of a steady state with the pump's pilot-valve law forced
        to one side of its kink (``'pos'``, ``'neg'``; ``None`` leaves it)."""
        return self.p_steady

    def input_step(self, k: int, u: np.ndarray) -> float:
        """The scale of input ``k`` at ``u`` for a difference step."""
        lo, hi = self.input_ranges[k]
        return max(abs(u[k]), (hi - lo) * 1e-3, 1e-9)

    def plant_params(self):
        """The pump's plant parameters (``hydropump_sim.params.Params``), if it has a pump."""
        return None

    # ---- section IV -----------------------------------------------------------------------

    def component_names(self) -> list[str]:
        """Its components, in order."""
        return []

    def reducible(self) -> dict[str, tuple[str, ...]]:
        """Section IV: the components with a static form -> the states it removes."""
        return {}

    def made_static(self, components) -> Model:
        """The model with the named components' fast dynamics made static."""
        return self

    def static_sets(self, components) -> dict:
        """The parameter values that make the named components static (a circuit's
        ``--set`` values; empty where the model has none)."""
        return {}

    # ---- the stepper's view ---------------------------------------------------------------

    @property
    def evaluate_c(self):
        raise NotImplementedError

    def structure(self) -> dict:
        """What :mod:`hydropump_sim.integrator` needs besides ``evaluate_c``: ``scale``,
        ``colors``, ``pattern``, ``timed``, ``dt_time``."""
        raise NotImplementedError

    def stepper_model(self, timed: bool | None = None) -> tuple:
        """The stepper's view (:func:`hydropump_sim.integrator.model`); ``timed=False`` drops
        the dither's time dependence (a steady-state march)."""
        from . import integrator
        st = self.structure()
        if timed is not None:
            st['timed'] = timed
        return integrator.model(self.evaluate_c, st)

    @property
    def p_steady(self) -> np.ndarray:
        """The packed parameters of a steady state (no dither)."""
        return self.p

    def evaluate(self, t, x, u, p, dx, y) -> None:
        """The compiled right-hand side and signals, called from Python."""
        from .integrator import call
        call(self.evaluate_c.address, t, x, u, p, dx, y)

    def rhs(self, t: float, x, u, p: np.ndarray | None = None
            ) -> tuple[np.ndarray, np.ndarray]:
        """State derivative and signals at one point (for analysis, not the inner loop)."""
        dx = np.empty(self.n_states)
        y = np.empty(self.n_signals)
        self.evaluate(float(t), np.ascontiguousarray(x, dtype=float),
                      np.ascontiguousarray(u, dtype=float), self.p if p is None else p, dx, y)
        return dx, y

    def jacobian(self, t, x, u, p: np.ndarray | None = None) -> np.ndarray:
        """``df/dx`` at one point, as the stepper forms it: forward differences, one
        evaluation per colour of the model's sparsity."""
        from .integrator import jacobian
        p = self.p if p is None else p
        st = self.structure()
        x = np.array(x, dtype=float)
        u = np.ascontiguousarray(u, dtype=float)
        f0, y = self.rhs(t, x, u, p)
        J = np.zeros((self.n_states, self.n_states))
        jacobian(self.evaluate_c.address, float(t), x, u, p, f0, st['scale'], J,
                 np.empty(self.n_states), y, st['colors'], st['pattern'])
        return J

    # ---- steady states --------------------------------------------------------------------

    def start_states(self, u: np.ndarray) -> list[np.ndarray]:
        """Where the steady-state search starts, best first."""
        raise NotImplementedError

    def unphysical(self, x: np.ndarray, u: np.ndarray) -> str | None:
        """Why ``x`` is not a steady state the model can hold at ``u``, or ``None``."""
        return None if np.all(np.isfinite(x)) else 'the state is not finite'

    # ---- inputs ---------------------------------------------------------------------------

    def input_vector(self, values: Mapping[str, float] | None = None) -> np.ndarray:
        """The held inputs with ``values`` (by name) over them, checked against each
        input's range."""
        u = self.u0.copy()
        errors = []
        for name, v in (values or {}).items():
            k = self.input_index(name)
            lo, hi = self.input_ranges[k]
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) \
                    or not lo <= v <= hi:
                hint = text_number_hint(v)
                errors.append(f'{name} = {v!r}: expected a number in [{lo:.6g}, {hi:.6g}] '
                              f'{self.input_units[k]}{hint}')
                continue
            u[k] = float(v)
        if errors:
            raise self.error(errors)
        return u

    def input_error(self, name: str, values: np.ndarray, t: np.ndarray) -> str:
        """One line for the first value of an input outside its range."""
        k = self.input_index(name)
        lo, hi = self.input_ranges[k]
        j = int(np.flatnonzero(~np.isfinite(values) | (values < lo) | (values > hi))[0])
        return (f'{name} = {values[j]:.6g} {self.input_units[k]} at t = {t[j]:.6g} s: '
                f'outside [{lo:.6g}, {hi:.6g}]')

    def input_table(self, t: np.ndarray, inputs: Mapping[str, Any] | None,
                    dt_held: float = 0.0, clamp: tuple[str, ...] = ()) -> tuple[np.ndarray,
                                                                                dict[str, int]]:
        """Held inputs on the increment times ``t`` (every input not named holds its
        value): each a number, a function of time or samples held for ``dt_held``. Values
        outside an input's range are an error, except for the inputs named in ``clamp``,
        which are limited to it and counted (``{name: samples clamped}``)."""
        from .inputs import sample
        U = np.tile(self.u0, (t.size, 1))
        errors, clamped = [], {}
        for name, sig in (inputs or {}).items():
            if sig is None:
                continue
            k = self.input_index(name)
            v = sample(sig, self.u0[k], t, name, dt_held)
            lo, hi = self.input_ranges[k]
            bad = ~np.isfinite(v) | (v < lo) | (v > hi)
            if bad.any() and name in clamp and np.all(np.isfinite(v)):
                clamped[name] = int(np.count_nonzero(bad))
                v = np.clip(v, lo, hi)
            elif bad.any():
                errors.append(self.input_error(name, v, t))
                continue
            U[:, k] = v
        if errors:
            raise InputError('; '.join(errors))
        return U, clamped


@dataclass
class Result:
    """A model's time response on a uniform grid (SI units, gauge pressures).

    ``res['pump.q_l']`` is a signal by name, ``res.input(name)`` an input; ``t``, ``y``
    (signals by column, ``model.signals``), ``x`` (states), ``u`` (held inputs).
    ``violations`` lists the physical invariants the run broke
    (:mod:`hydropump_sim.invariants`).
    """

    model: Model
    t: np.ndarray
    y: np.ndarray
    x: np.ndarray
    u: np.ndarray
    stats: dict = field(default_factory=dict)
    violations: list = field(default_factory=list)

    @property
    def circuit(self) -> Model:
        return self.model

    def __getitem__(self, name: str) -> np.ndarray:
        return self.y[:, self.model.signal_index(name)]

    def input(self, name: str) -> np.ndarray:
        return self.u[:, self.model.input_index(name)]

    def node(self, node: str) -> np.ndarray:
        """Pressure of a node [Pa gauge]."""
        return self[f'node:{node}']

    def final(self) -> dict[str, float]:
        """Every signal a user reads, its last value, by name."""
        return {n: float(self[n][-1]) for n in self.model.component_signals()}

    def to_npz(self, path: str | Path) -> None:
        m = self.model
        with replacing(path, 'result') as tmp:
            np.savez_compressed(tmp, t=self.t, y=self.y, x=self.x, u=self.u,
                                signals=np.array(m.signals), units=np.array(m.signal_units),
                                states=np.array(m.states), inputs=np.array(m.inputs))

    def to_csv(self, path: str | Path, names: list[str] | None = None) -> None:
        """Time and the named signals (default every signal a user reads) with units."""
        m = self.model
        names = names or m.component_signals()
        cols = [self[n] for n in names]
        units = [m.signal_units[m.signal_index(n)] for n in names]
        head = 't [s],' + ','.join(f'{n} [{u}]' for n, u in zip(names, units))
        with replacing(path, 'result') as tmp:
            np.savetxt(tmp, np.column_stack([self.t] + cols), delimiter=',', header=head,
                       comments='', fmt='%.10g')


@dataclass
class SteadyState:
    """A steady state: states, held inputs, signals; ``eq['boom.flow']`` by name."""

    model: Model
    x: np.ndarray
    u: np.ndarray
    y: np.ndarray
    residual: float

    @property
    def circuit(self) -> Model:
        return self.model

    def __getitem__(self, name: str) -> float:
        return float(self.y[self.model.signal_index(name)])
