"""The paper's plant alone as a :class:`~hydropump_sim.system.Model`: the pump of eqs. 1-8,
the line volume, the load of eq. 9 and the relief valve of Fig. 1, in the fixed layout of
:mod:`hydropump_sim._core` (fine, simplified or simplified keeping ``K_c``).

Its names are those of ``config/circuits/paper.yaml``, the same plant as a circuit: inputs
``pump.current`` (absolute, eq. 2), ``load.load_pressure``, ``load.aperture``,
``pump.shaft_speed``; signals ``pump.<output>``, ``load.flow``, ``load.load_pressure``,
``relief.flow``; states ``pump.x_c .. pump.P_a``, ``node:line`` (the line pressure) and
``pump.i`` (the solenoid current, with its lag). So whatever reads a model by name reads
either.

Its steady states start from the closed form with ``x_c = 0`` (exact without leakage and
end stops), or the standby state where the line pressure is too low to hold the demanded
displacement; a state with the actuator pressure outside ``[P_T, P_l]`` is not one the
pump can hold (D5: the pilot feedback reverses).
"""

from __future__ import annotations

import numpy as np
from scipy import optimize

from . import _core as c
from .components.orifice_load import OrificeLoad
from .components.pump import Pump
from .measure import SIGNALS
from .model import OUTPUTS, pack, state_names
from .params import input_spec, Params
from .steady import TrimError
from .system import Model

#: The paper's output names -> the model's signal names (paper.yaml's).
SIGNAL_NAMES = {'I_s': 'pump.current', 'x_c': 'pump.x_c', 'v_c': 'pump.v_c',
                'x_a': 'pump.x_a', 'v_a': 'pump.v_a', 'P_a': 'pump.P_a', 'P_l': 'pump.P_l',
                'Q_p': 'pump.Q_p', 'Q_a': 'pump.Q_a', 'q_l': 'pump.q_l', 'Q_load': 'load.flow',
                'Q_relief': 'relief.flow', 'P_u': 'load.load_pressure'}
#: The paper's state names -> the model's.
STATE_NAMES = {'x_c': 'pump.x_c', 'v_c': 'pump.v_c', 'x_a': 'pump.x_a', 'v_a': 'pump.v_a',
               'P_a': 'pump.P_a', 'P_l': 'node:line', 'i': 'pump.i'}
#: The inputs, in ``_core``'s order, with the plant parameter whose range each shares.
INPUT_NAMES = ('pump.current', 'load.load_pressure', 'load.aperture', 'pump.shaft_speed')
_UNITS = {'pump.current': 'A', 'load.load_pressure': 'Pa', 'load.aperture': '-',
          'pump.shaft_speed': 'Hz'}
_STATE_UNITS = {'x_c': 'm', 'v_c': 'm/s', 'x_a': 'm', 'v_a': 'm/s', 'P_a': 'Pa', 'P_l': 'Pa',
                'i': 'A'}
_OUTPUT_UNITS = ('A', 'm', 'm/s', 'm', 'm/s', 'Pa', 'Pa', 'm^3/s', 'm^3/s', 'm^3/s', 'm^3/s',
                 'm^3/s', 'Pa')
#: The suite's measured signals it gives: what its two components, named ``pump`` and
#: ``load`` as in config/circuits/paper.yaml, declare they measure.
_DECLARED = {**{s: f'pump.{v}' for s, v in Pump.MEASURES.items()},
             **{s: f'load.{v}' for s, v in OrificeLoad.MEASURES.items()}}
MEASURED = {s: _DECLARED[s] for s in SIGNALS if s in _DECLARED}


def operating_inputs(params: Params, current: float | None = None, *, load_pressure=None,
                     aperture=None, shaft_speed=None) -> np.ndarray:
    """Input vector ``[I_s, P_u, xi_u, f_p]`` (absolute current); ``None`` = the params
    file's operating point (50 % displacement for the current)."""
    ln = params.line
    return np.array([params.I_nominal if current is None else current,
                     ln.P_u if load_pressure is None else load_pressure,
                     ln.xi_u if aperture is None else aperture,
                     params.pump.f_p if shaft_speed is None else shaft_speed], dtype=float)


class PumpModel(Model):
    """The paper's plant (see the module).

    Parameters
    ----------
    params : Params
    model : {'fine', 'simplified', 'simplified_Kc'}
    branch : {None, 'pos', 'neg'}
        The pilot valve's law forced to one side of its kink (one-sided linearisations).
    """

    def __init__(self, params: Params, model: str = 'fine', branch: str | None = None):
        self.params = params
        self.fluid = params.fluid
        self.model = model
        self.branch = branch
        self.name = 'paper' if model == 'fine' else f'paper ({model})'
        names = state_names(params, model)
        self.paper_states = names
        self.states = [STATE_NAMES[n] for n in names]
        self.state_units = [_STATE_UNITS[n] for n in names]
        self.p = pack(params, model, branch)
        self.state_scale = np.asarray(c.state_scale(self.p, len(names)), dtype=float)
        self.integrating = np.zeros(len(names), dtype=bool)
        self.inputs = list(INPUT_NAMES)
        self.input_units = [_UNITS[n] for n in INPUT_NAMES]
        self.input_ranges = [params.I_limits] + [input_spec(n).range for n in
                                                  ('load_pressure', 'aperture', 'shaft_speed')]
        self.u0 = operating_inputs(params)
        self.signals = [SIGNAL_NAMES[o] for o in OUTPUTS]
        self.signal_units = list(_OUTPUT_UNITS)
        inp = params.input
        self.dither = inp.dither_freq if inp.dither_amp > 0.0 else 0.0

    def _alias(self, name: str, kind: str) -> str:
        if kind == 'signals':
            if name == 'node:line':
                return 'pump.P_l'
            return SIGNAL_NAMES.get(name, name)
        return name

    # ---- the stepper's view ---------------------------------------------------------------

    @property
    def evaluate_c(self):
        return c.evaluate_c

    def structure(self) -> dict:
        return c.structure(self.p, self.n_states)

    @property
    def p_steady(self) -> np.ndarray:
        p = self.p.copy()
        p[c.P_DITHA] = 0.0  # the mean current defines the steady state
        return p

    def branch_p(self, branch: str | None) -> np.ndarray:
        p = pack(self.params, self.model, branch)
        p[c.P_DITHA] = 0.0
        return p

    def input_step(self, k: int, u: np.ndarray) -> float:
        return (self.params.spool.I_max, 1.0e6, 0.1, 1.0)[k]

    def with_params(self, params: Params) -> PumpModel:
        return PumpModel(params, self.model, self.branch)

    # ---- roles ----------------------------------------------------------------------------

    def measured(self) -> dict[str, str]:
        return dict(MEASURED)

    def plant_inputs(self) -> dict[str, str]:
        return dict(zip(('current', 'load_pressure', 'aperture', 'shaft_speed'), INPUT_NAMES))

    def electric_pump(self) -> bool:
        return True

    def pump_name(self) -> str:
        return 'pump'

    def relieved(self) -> list[str]:
        return ['relief.flow']

    def input_error(self, name: str, values: np.ndarray, t: np.ndarray) -> str:
        """The paper plant's inputs take the ranges (and unit hints) of their plant
        parameters."""
        from .params import check_input
        paper = {'load.load_pressure': 'load_pressure', 'load.aperture': 'aperture',
                 'pump.shaft_speed': 'shaft_speed'}
        if name in paper:
            return check_input(paper[name], values, t) or super().input_error(name, values, t)
        return super().input_error(name, values, t)

    def plant_params(self) -> Params:
        return self.params

    @property
    def volume(self) -> dict[str, float]:
        """The line's volume (the node of its line pressure) [m^3]."""
        return {'line': self.params.line.V_l}

    def component_names(self) -> list[str]:
        return ['pump']

    def reducible(self) -> dict[str, tuple[str, ...]]:
        """Section IV on the pump: eq. 10 makes its spool and plate quasi-static, keeping
        ``x_a`` and the line pressure (the simplified model, keeping ``K_c``)."""
        if self.model != 'fine':
            return {}
        return {'pump': tuple(s for s in self.states if s not in ('pump.x_a', 'node:line'))}

    def made_static(self, components) -> Model:
        if 'pump' in components and self.model == 'fine':
            return PumpModel(self.params, 'simplified_Kc', self.branch)
        return self

    def pressure_nodes(self) -> list[tuple[str, str]]:
        """The hydraulic nodes and the signal of each one's pressure."""
        return [('line', 'pump.P_l'), ('actuator', 'pump.P_a')]

    def pressure_caps(self, U: np.ndarray) -> np.ndarray:
        """The highest pressure a source makes at each row of ``U``: the relief valve's
        full-flow pressure plus one regulation range, or the held load pressure; with the
        relief valve disabled nothing limits the pump (``nan``: no cap to check)."""
        rl = self.params.relief
        if not rl.enabled:
            return np.full(U.shape[0], np.nan)
        return np.fmax(2.0 * rl.p_full - rl.p_crack, U[:, c.U_PU])

    # ---- steady states --------------------------------------------------------------------

    def start_states(self, u: np.ndarray) -> list[np.ndarray]:
        out = [seed_state(self.params, u, self.model)]
        if self.model == 'fine':
            standby = standby_seed(self.params, u, self.p)
            if standby is not None:
                out.append(standby)
        return out

    def clip_start(self, x: np.ndarray) -> np.ndarray:
        """A start the dynamics can march from: pressures inside ``[P_T, P_l]``."""
        x = x.copy()
        if self.model == 'fine':
            P_T = self.params.fluid.P_T
            x[5] = max(x[5], P_T)
            x[4] = min(max(x[4], P_T), x[5])
        return x

    def unphysical(self, x: np.ndarray, u: np.ndarray) -> str | None:
        """Why ``x`` is not a steady state the pump can hold: pressures above absolute zero,
        the actuator between tank and line pressure (D5; otherwise the pilot feedback
        reverses), parts near their stroke."""
        params = self.params
        if not np.all(np.isfinite(x)):
            return 'the state is not finite'
        _, y = self.rhs(0.0, x, u, self.p_steady)
        P_a, P_l, x_a, x_c = y[c.Y_PA], y[c.Y_PL], y[c.Y_XA], y[c.Y_XC]
        slack = 1.0e4  # Pa: the regularised orifice lets P_a sit a little outside P_T..P_l
        if P_l + params.fluid.p_atm < 0.0:
            return f'the line pressure P_l = {P_l:.4g} Pa is below absolute zero'
        if not params.fluid.P_T - slack <= P_a <= P_l + slack:
            return (f'the actuator pressure P_a = {P_a:.4g} Pa is outside [P_T, P_l] = '
                    f'[{params.fluid.P_T:.4g}, {P_l:.4g}] Pa (D5: the pilot feedback '
                    'reverses)')
        if abs(x_a) > 1.5 * params.x_a_stop:
            return f'the plate is at x_a = {x_a:.4g} m, beyond its stroke {params.x_a_stop:.4g} m'
        if abs(x_c) > 1.5 * params.spool.x_c_max:
            return (f'the spool is at x_c = {x_c:.4g} m, beyond its stroke '
                    f'{params.spool.x_c_max:.4g} m')
        return None

    def describe_inputs(self, u: np.ndarray) -> str:
        return (f'I_s = {u[0]:.4g} A, P_u = {u[1]:.4g} Pa, xi_u = {u[2]:.4g}, '
                f'f_p = {u[3]:.4g} Hz')


def _line_pressure(p: np.ndarray, Q_p: float, u: np.ndarray) -> float:
    """Line pressure that balances pump flow against load and relief flows (eq. 9)."""
    def surplus(P_l):
        Q_load = p[c.P_MUU] * u[c.U_XI] * c.groot(P_l - u[c.U_PU], p[c.P_DPCRU], p[c.P_GAMMA])
        return Q_p - Q_load - c.relief_flow(P_l, p)

    if Q_p <= 0.0:
        return float(u[c.U_PU])  # no flow: the line rests at the load pressure
    lo, hi = max(u[c.U_PU] - 1.0e7, -float(p[c.P_PATM])), 1.0e9
    if surplus(hi) > 0.0:
        raise TrimError('no equilibrium: the pump flow has nowhere to go (load aperture '
                        'closed and relief valve disabled)')
    if surplus(lo) < 0.0:
        return lo
    return optimize.brentq(surplus, lo, hi, xtol=1e-9, rtol=1e-14, maxiter=500)


def seed_state(params: Params, u: np.ndarray, model: str = 'fine') -> np.ndarray:
    """Closed-form equilibrium with ``x_c = 0`` (exact without leakage and end stops)."""
    p = pack(params, model)
    sp = params.spool
    i_s = u[c.U_I] - params.I_nominal
    x_a = float(np.clip(sp.phi_s * i_s / sp.K_a, -params.x_a_stop, params.x_a_stop))
    Q_p = c.pump_flow(x_a, u[c.U_FP], p)
    P_l = _line_pressure(p, Q_p, u)
    if model != 'fine':
        return np.array([x_a, P_l])
    x_c = (sp.phi_s * i_s - sp.K_a * x_a) / (sp.K_a + sp.K_c)
    # Eq. 6 at rest gives the actuator pressure that holds the plate (eq. 12, first line).
    P_a = params.actuator.P_a_bar - (params.plate.K_b * x_a + sp.K_a * (x_a + x_c)
                                     + (P_l - params.line.P_l_bar) * params.plate.S_d
                                     ) / params.actuator.S_a
    x = [x_c, 0.0, x_a, 0.0, P_a, P_l]
    if params.input.tau_s > 0.0:
        x.append(i_s)
    return np.array(x)


def standby_seed(params: Params, u: np.ndarray, p: np.ndarray) -> np.ndarray | None:
    """Steady state with the pilot valve open to the line (``P_a = P_l``): the line pressure
    is too low to hold the demanded displacement, so the pump settles where the line pressure
    on the actuator balances the bias spring (a pump's standby pressure)."""
    sp, S_a, S_d = params.spool, params.actuator.S_a, params.plate.S_d
    i_s = u[c.U_I] - params.I_nominal

    def state(x_a):
        x_c = (sp.phi_s * i_s - sp.K_a * x_a) / (sp.K_a + sp.K_c)
        x_c = min(max(x_c, -sp.x_c_max), sp.x_c_max)
        P_l = ((params.actuator.P_a_bar * S_a + params.line.P_l_bar * S_d
                - params.plate.K_b * x_a - sp.K_a * (x_a + x_c)) / (S_a + S_d))
        return x_c, P_l

    def surplus(x_a):
        x_c, P_l = state(x_a)
        Q_load = p[c.P_MUU] * u[c.U_XI] * c.groot(P_l - u[c.U_PU], p[c.P_DPCRU], p[c.P_GAMMA])
        return c.pump_flow(x_a, u[c.U_FP], p) - Q_load - c.relief_flow(P_l, p)

    lo, hi = -params.x_a_stop, params.x_a_stop
    if surplus(lo) * surplus(hi) > 0.0:
        return None
    x_a = optimize.brentq(surplus, lo, hi, xtol=1e-15)
    x_c, P_l = state(x_a)
    x = [x_c, 0.0, x_a, 0.0, P_l, P_l]
    if params.input.tau_s > 0.0:
        x.append(i_s)
    return np.array(x)
