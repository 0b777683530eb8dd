"""The pump: the paper's electro-hydraulic variable-displacement axial-piston pump with
mechanical feedback, eqs. 1-8, delivering into the node of its port ``out`` (the line).

Its equations are written once, in :func:`pump_equations`: the paper's plant alone
(:mod:`hydropump_sim._core`, the fixed layout of ``simulate()``) and this component both call
them. Parameters are a plant params file's (``config/pump.yaml``; a circuit's ``plant:``), the
packed layout is ``P_*`` below; the line's own entries (``line.V_l``, the load of eq. 9, the
relief valve) belong to the circuit's volume, load and relief components, except
``line.P_l_bar`` (eq. 7).

Models: ``fine`` (eqs. 1-8; states ``x_c, v_c, x_a, v_a, P_a`` and the solenoid current
``i`` when ``input.tau_s > 0``), ``simplified`` (eq. 10 as printed: state ``x_a``) and
``simplified_Kc`` (eq. 10 keeping ``K_c``).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
import math
from typing import Any

import numpy as np

from ..jitcache import jit
from ..params import Params, params_from_dict
from ..schema import build, ParamError, spec
from .base import Component, InputSpec, PortSpec, SignalSpec, StateSpec
from .laws import continuity, sroot, stop_force

FINE, SIMPLIFIED, SIMPLIFIED_KC = 0, 1, 2
MODELS = {'fine': FINE, 'simplified': SIMPLIFIED, 'simplified_Kc': SIMPLIFIED_KC}
BRANCHES = {None: 0.0, 'natural': 0.0, 'pos': 1.0, 'neg': -1.0}

# Packed parameter vector layout.
(P_BETA, P_ALPHA, P_PATM, P_PT, P_FLOOR, P_DPFLOOR,
 P_VP, P_STROKE, P_XASTOP, P_DISPCLIP,
 P_MC, P_KC, P_KA, P_PHI, P_XCMAX, P_CC, P_FCC, P_VEPSC, P_KSTOPC, P_CSTOPC,
 P_SA, P_VA0, P_VAMIN, P_PABAR, P_MUA, P_DPCRA, P_GLEAK,
 P_MA, P_KB, P_SD, P_CA, P_FCA, P_VEPSA, P_KSTOPA, P_CSTOPA,
 P_VL, P_PLBAR, P_GAMMA, P_MUU, P_DPCRU,
 P_RELIEF, P_PCRACK, P_PFULL, P_QFULL,
 P_DITHA, P_DITHF, P_TAUS, P_IMIN, P_IMAX,
 P_MODEL, P_BRANCH, N_P) = range(52)

# The pump's signals, in the order pump_equations writes them.
(Y_IS, Y_XC, Y_VC, Y_XA, Y_VA, Y_PA, Y_PL, Y_QP, Y_QA, Y_QL, N_PUMP_Y) = range(11)


def model_code(model: str) -> int:
    """Translate a model name into its kernel code, with a clear error."""
    try:
        return MODELS[model]
    except KeyError:
        raise ValueError(f'unknown model {model!r}: choose one of {", ".join(MODELS)}') \
            from None


def pack(params: Params, model: str = 'fine', branch: str | None = None) -> np.ndarray:
    """Packed parameter vector of :func:`pump_equations` (SI).

    Parameters
    ----------
    params : Params
        Validated plant parameters.
    model : {'fine', 'simplified', 'simplified_Kc'}
        Which equations to evaluate.
    branch : {None, 'pos', 'neg'}
        Force the pilot-valve law of eq. 4 to one side of ``x_c = 0`` (one-sided
        linearisation, docs/reference.md I2); ``None`` follows the sign of ``x_c``.
    """
    f, pu, sp, ac, pl, ln, rl, inp = (params.fluid, params.pump, params.spool, params.actuator,
                                      params.plate, params.line, params.relief, params.input)
    p = np.zeros(N_P)
    p[P_BETA] = f.beta
    p[P_ALPHA] = f.alpha_air
    p[P_PATM] = f.p_atm
    p[P_PT] = f.P_T
    p[P_FLOOR] = float(f.pressure_floor)
    p[P_DPFLOOR] = f.dp_floor
    p[P_VP] = pu.V_p
    p[P_STROKE] = params.stroke_scale
    p[P_XASTOP] = params.x_a_stop
    p[P_DISPCLIP] = float(pu.disp_clip)
    p[P_MC] = sp.m_c
    p[P_KC] = sp.K_c
    p[P_KA] = sp.K_a
    p[P_PHI] = sp.phi_s
    p[P_XCMAX] = sp.x_c_max
    p[P_CC] = sp.c_c
    p[P_FCC] = sp.F_coul_c
    p[P_VEPSC] = sp.v_eps_c
    p[P_KSTOPC] = sp.k_stop_c
    p[P_CSTOPC] = sp.c_stop_c
    p[P_SA] = ac.S_a
    p[P_VA0] = ac.V_a0
    p[P_VAMIN] = ac.V_a_min
    p[P_PABAR] = ac.P_a_bar
    p[P_MUA] = ac.mu_a
    p[P_DPCRA] = ac.dp_cr_a
    p[P_GLEAK] = ac.G_leak_a
    p[P_MA] = pl.m_a
    p[P_KB] = pl.K_b
    p[P_SD] = pl.S_d
    p[P_CA] = pl.c_a
    p[P_FCA] = pl.F_coul_a
    p[P_VEPSA] = pl.v_eps_a
    p[P_KSTOPA] = pl.k_stop_a
    p[P_CSTOPA] = pl.c_stop_a
    p[P_VL] = ln.V_l
    p[P_PLBAR] = ln.P_l_bar
    p[P_GAMMA] = ln.gamma_u
    p[P_MUU] = ln.mu_u
    p[P_DPCRU] = ln.dp_cr_u
    p[P_RELIEF] = float(rl.enabled)
    p[P_PCRACK] = rl.p_crack
    p[P_PFULL] = rl.p_full
    p[P_QFULL] = rl.q_full
    p[P_DITHA] = inp.dither_amp
    p[P_DITHF] = inp.dither_freq
    p[P_TAUS] = inp.tau_s if model == 'fine' else 0.0
    p[P_IMIN] = sp.I_min
    p[P_IMAX] = sp.I_max
    p[P_MODEL] = model_code(model)
    try:
        p[P_BRANCH] = BRANCHES[branch]
    except KeyError:
        raise ValueError(f'unknown branch {branch!r}: choose pos or neg') from None
    return p


def state_names(params: Params, model: str = 'fine') -> tuple[str, ...]:
    """The pump's own states (the line pressure is its port's node)."""
    if model != 'fine':
        return ('x_a',)
    return ('x_c', 'v_c', 'x_a', 'v_a', 'P_a') + (('i',) if params.input.tau_s > 0.0 else ())


@jit
def pilot_flows(x_c, P_a, P_l, p):
    """Pilot valve, eq. 4: return ``(Q_a, Q_from_line)``, ``Q_a > 0`` out of the actuator.

    ``x_c > 0`` drains the actuator to tank; ``x_c < 0`` feeds it from the line. The branch
    can be forced (``p[P_BRANCH]`` = +1 or -1) for the one-sided linearisations (I2).
    """
    branch = p[P_BRANCH]
    if branch == 0.0:
        branch = 1.0 if x_c >= 0.0 else -1.0
    leak = p[P_GLEAK] * (P_a - p[P_PT])
    if branch > 0.0:
        return p[P_MUA] * x_c * sroot(P_a - p[P_PT], p[P_DPCRA]) + leak, 0.0
    q = p[P_MUA] * x_c * sroot(P_l - P_a, p[P_DPCRA])
    return q + leak, q


@jit
def pump_flow(x_a, f_p, p):
    """Eq. 8 (``flow_map`` reading in ``P_STROKE``), clipped to the displacement range."""
    disp = 0.5 + x_a / p[P_STROKE]
    if p[P_DISPCLIP] > 0.0:
        disp = min(max(disp, 0.0), 1.0)
    return p[P_VP] * f_p * disp


@jit
def chamber_rate(P, flow, volume, p):
    """Continuity of a pump chamber with the pump's fluid entries (eq. 3)."""
    return continuity(P, flow, volume, p[P_BETA], p[P_ALPHA], p[P_PATM], p[P_FLOOR],
                      p[P_DPFLOOR])


@jit
def pump_equations(t, x, dx, i_idx, P_l, i_var, f_p, p, y):
    """The pump's state rates and signals at line pressure ``P_l``; returns the flow it
    delivers into the line, ``q_l = Q_p + Q_in`` [m^3/s] (eqs. 8-9).

    Parameters
    ----------
    t : float
        Time [s] (dither phase).
    x, dx : ndarray
        Fine: ``x_c, v_c, x_a, v_a, P_a`` at 0..4 [m, m/s, m, m/s, Pa gauge] and the solenoid
        current at ``i_idx`` [A] when ``tau_s > 0``; simplified: ``x_a`` at 0.
    i_idx : int
        Index of the solenoid current state.
    P_l : float
        Line pressure [Pa gauge].
    i_var, f_p : float
        Current variation ``i_s`` of eq. 2 [A] and shaft frequency [Hz].
    p : ndarray
        Packed parameters (:func:`pack`).
    y : ndarray
        Filled with the signals ``Y_*`` (``N_PUMP_Y``).
    """
    i_ref = i_var
    if p[P_DITHA] > 0.0:
        i_ref += p[P_DITHA] * math.sin(2.0 * math.pi * p[P_DITHF] * t)
    model = p[P_MODEL]
    if model == FINE:
        x_c = x[0]
        v_c = x[1]
        x_a = x[2]
        v_a = x[3]
        P_a = x[4]
        if p[P_TAUS] > 0.0:
            i_s = x[i_idx]
            dx[i_idx] = (i_ref - i_s) / p[P_TAUS]
        else:
            i_s = i_ref
        # Eq. 1: spool; A_c = viscous + smoothed Coulomb; end stops at +-x_c_max (I13).
        F_c = (-p[P_CC] * v_c - p[P_FCC] * math.tanh(v_c / p[P_VEPSC])
               - (p[P_KC] + p[P_KA]) * x_c - p[P_KA] * x_a + p[P_PHI] * i_s
               + stop_force(x_c, v_c, p[P_XCMAX], p[P_KSTOPC], p[P_CSTOPC]))
        # Eq. 4: pilot valve; eq. 3: actuator continuity with V_a = V_a0 - S_a x_a (I14).
        Q_a, Q_in = pilot_flows(x_c, P_a, P_l, p)
        V_a = max(p[P_VA0] - p[P_SA] * x_a, p[P_VAMIN])
        # Eq. 6 with the variational pressures of eq. 7.
        F_a = (-p[P_CA] * v_a - p[P_FCA] * math.tanh(v_a / p[P_VEPSA])
               - p[P_KB] * x_a - p[P_KA] * (x_a + x_c)
               - (P_a - p[P_PABAR]) * p[P_SA] - (P_l - p[P_PLBAR]) * p[P_SD]
               + stop_force(x_a, v_a, p[P_XASTOP], p[P_KSTOPA], p[P_CSTOPA]))
        dx[0] = v_c
        dx[1] = F_c / p[P_MC]
        dx[2] = v_a
        dx[3] = F_a / p[P_MA]
        dx[4] = chamber_rate(P_a, -Q_a + p[P_SA] * v_a, V_a, p)
    else:
        x_a = x[0]
        i_s = i_ref
        # Eq. 10: quasi-static spool (as printed, or keeping K_c: I8), inside its stops.
        if model == SIMPLIFIED:
            x_c = p[P_PHI] * i_s / p[P_KA] - x_a
        else:
            x_c = (p[P_PHI] * i_s - p[P_KA] * x_a) / (p[P_KA] + p[P_KC])
        if p[P_KSTOPC] > 0.0:
            x_c = min(max(x_c, -p[P_XCMAX]), p[P_XCMAX])
        # Eq. 12, first line (keeps p_l S_d: I9); K_a (x_a + x_c) = phi_s i_s for eq. 10.
        P_a = p[P_PABAR] - (p[P_KB] * x_a + p[P_KA] * (x_a + x_c)
                            + (P_l - p[P_PLBAR]) * p[P_SD]) / p[P_SA]
        Q_a, Q_in = pilot_flows(x_c, P_a, P_l, p)
        v_a = Q_a / p[P_SA]
        if p[P_KSTOPA] > 0.0 and ((x_a >= p[P_XASTOP] and v_a > 0.0)
                                  or (x_a <= -p[P_XASTOP] and v_a < 0.0)):
            v_a = 0.0
        v_c = 0.0
        dx[0] = v_a
    # Eq. 8, and eq. 9's inflow: the pilot valve takes from the line only for x_c < 0.
    Q_p = pump_flow(x_a, f_p, p)
    q_l = Q_p + Q_in
    y[Y_IS] = p[P_IMIN] + p[P_IMAX] + i_s
    y[Y_XC] = x_c
    y[Y_VC] = v_c
    y[Y_XA] = x_a
    y[Y_VA] = v_a
    y[Y_PA] = P_a
    y[Y_PL] = P_l
    y[Y_QP] = Q_p
    y[Y_QA] = Q_a
    y[Y_QL] = q_l
    return q_l


@jit
def state_scale(p, n):
    """Typical magnitude of each pump state, for tolerances and finite differences."""
    s = np.empty(n)
    if p[P_MODEL] == FINE:
        s[0] = p[P_XCMAX]
        s[1] = 0.1
        s[2] = p[P_XASTOP]
        s[3] = 0.1
        s[4] = 1.0e6
        for k in range(5, n):
            s[k] = p[P_IMAX]
    else:
        s[0] = p[P_XASTOP]
    return s


# ---- the circuit component ---------------------------------------------------------------

# The component's packed vector: the nodes of its ports (out, ls), then the pump's ``P_*`` layout.
C_OUT, C_P = 0, 2
# Its inputs: the absolute solenoid current [A] and the shaft frequency [Hz].
U_CURRENT, U_SPEED = 0, 1


#: The lead of a cut-off's regulator: (1 + s T) / (1 + s T / LEAD_RATIO).
LEAD_RATIO = 10.0


@jit
def cutoff(x, dx, P_l, c):
    """The pressure cut-off's override of the pilot spool's command (in the command's
    units, 0 below its setting) from its packed ``c = [p_set, gain, lead]``, and the rate
    of its lead filter (its last state ``x[-1]`` when it has one). Returns the override and
    how many of ``x`` are the pump's own."""
    p_set, gain, lead = c[0], c[1], c[2]
    n = x.shape[0]
    if p_set <= 0.0:
        return 0.0, n
    p_eff = P_l
    if lead > 0.0:
        f = x[n - 1]
        dx[n - 1] = (P_l - f) * LEAD_RATIO / lead
        p_eff = P_l + (LEAD_RATIO - 1.0) * (P_l - f)
        n -= 1
    if p_eff <= p_set:
        return 0.0, n
    return (p_eff - p_set) * gain, n


@jit
def kernel(t, x, dx, u, p, y, P, Q, V):
    """The pump in a circuit: ``u = [I_s (absolute, clamped to eq. 2), f_p]``."""
    out = int(p[C_OUT])
    q = p[C_P:C_P + N_P]
    lo = q[P_IMIN]
    current = min(max(u[U_CURRENT], lo), lo + 2.0 * q[P_IMAX])
    over, n = cutoff(x, dx, P[out], p[C_P + N_P:])
    q_l = pump_equations(t, x[:n], dx[:n], n - 1, P[out],
                         current - over - (q[P_IMIN] + q[P_IMAX]), u[U_SPEED], q, y)
    Q[out] += q_l
    y[Y_SUPPLY] = P[out] * q_l
    y[Y_IS] += over  # the solenoid's own current: the cut-off acts on the spool


@dataclass(frozen=True)
class Cutoff:
    """A pressure cut-off (the pressure compensator of a load-sensing pump): a spool that
    destrokes the pump when its outlet pressure exceeds ``p_set``, overriding the pump's
    command fully ``band`` above it. Its regulator sees the pressure through a lead
    ``(1 + s T) / (1 + s T/10)``, as Hopsan's pressure-controlled pump does (``omega_p1``,
    200 rad/s): without it the line's integrator behind the plate's lag would ring at the
    cut-off (a 10 bar band on a 420 L/min pump: 220 rad/s, zeta 0.02)."""

    p_set: float = spec('Pa', 'cut-off pressure; 0 = none', 0.0, 6.0e7, default=0.0)
    band: float = spec('Pa', 'pressure rise over p_set that destrokes the pump fully', 1.0e4,
                       5.0e6, default=1.0e6)
    lead: float = spec('s', "the regulator's lead time constant T; 0 = none (Hopsan: 1/200 "
                       'rad/s)', 0.0, 1.0, default=5.0e-3)


@dataclass(frozen=True)
class PumpSetup:
    """The pump component's parameters: a plant parameter set, the model to run, its
    pressure cut-off."""

    plant: Params
    model: str = 'fine'
    cutoff: Cutoff = Cutoff()


def cutoff_state(cut: Cutoff) -> tuple[StateSpec, ...]:
    """The cut-off's lead filter, the pump's last state when it has one."""
    return (StateSpec('cutoff', 'Pa', 1.0e6),) if cut.p_set > 0.0 and cut.lead > 0.0 else ()


def split_cutoff(values: Mapping[str, Any], source: str | None) -> tuple[dict, Cutoff]:
    """A pump's entries without its ``cutoff.*`` ones, and its :class:`Cutoff`."""
    rest = {k: v for k, v in values.items() if not k.startswith('cutoff.')}
    own = {k[len('cutoff.'):]: v for k, v in values.items() if k.startswith('cutoff.')}
    return rest, build(Cutoff, own, source)


SIGNAL_UNITS = (('current', 'A', 'solenoid current I_s (eq. 2)'),
                ('x_c', 'm', 'pilot spool position (eq. 1)'),
                ('v_c', 'm/s', 'pilot spool velocity'),
                ('x_a', 'm', 'swash-plate actuator position (eq. 6)'),
                ('v_a', 'm/s', 'actuator velocity'),
                ('P_a', 'Pa', 'actuator pressure (eq. 3)'),
                ('P_l', 'Pa', 'line pressure at the outlet (eq. 9)'),
                ('Q_p', 'm^3/s', 'geometric pump flow (eq. 8)'),
                ('Q_a', 'm^3/s', 'pilot flow out of the actuator (eq. 4)'),
                ('q_l', 'm^3/s', 'flow delivered into the line, Q_p plus the pilot inflow'),
                ('supply', 'W', 'hydraulic power delivered, P_l q_l'))
#: Where the pump's ``supply`` signal is.
Y_SUPPLY = len(SIGNAL_UNITS) - 1


class Pump(Component):
    kind = 'pump'
    doc = "the paper's pump, eqs. 1-8, parameters from a plant params file"
    PORTS = (PortSpec('out', 'pump outlet: the line'),
             PortSpec('ls', 'load-sensing line, unused by this pump (the hydromechanical '
                      'ls_pump reads it): a circuit can switch type and keep its ports',
                      optional=True, sense=True))
    INPUTS = (InputSpec('current', 'A', 'solenoid current command (clamped to eq. 2)',
                        0.0, 10.0, 'I_nominal'),
              InputSpec('shaft_speed', 'Hz', 'shaft frequency', 1.0, 100.0, 'f_p'))
    SIGNALS = tuple(SignalSpec(*s) for s in SIGNAL_UNITS)
    kernel = kernel
    ROLES = frozenset({'pump', 'electric'})
    MEASURES = {'pump_flow': 'Q_p', 'line_flow': 'q_l', 'actuator_pressure': 'P_a',
                'line_pressure': 'P_l', 'spool_position': 'x_c', 'actuator_position': 'x_a',
                'solenoid_current': 'current'}
    PLANT_INPUTS = True
    #: Its parameters start from the circuit's plant params file.
    PLANT_PARAMS = True
    #: Where the pump's ``P_*`` layout starts in its packed vector.
    P_OFFSET = C_P

    @classmethod
    def build_params(cls, values: Mapping[str, Any], source: str | None = None) -> PumpSetup:
        values, cut = split_cutoff(values, source)
        model = values.pop('model', 'fine')
        if model not in MODELS:
            raise ParamError([f'model = {model!r}: expected one of {", ".join(MODELS)}'],
                             source)
        return PumpSetup(params_from_dict(values, source), model, cut)

    @classmethod
    def param_specs(cls):
        from ..params import iter_specs
        from ..schema import specs_of
        return {**{s.name: s for s in iter_specs()},
                **{f'cutoff.{s.name}': s for s in specs_of(Cutoff)}}

    def states(self):
        plant = self.params.plant
        scale = dict(zip(('x_c', 'v_c', 'x_a', 'v_a', 'P_a', 'i'),
                         (plant.spool.x_c_max, 0.1, plant.x_a_stop, 0.1, 1.0e6,
                          plant.spool.I_max)))
        units = {'x_c': 'm', 'v_c': 'm/s', 'x_a': 'm', 'v_a': 'm/s', 'P_a': 'Pa', 'i': 'A'}
        return tuple(StateSpec(n, units[n], scale[n])
                     for n in state_names(plant, self.params.model)) + cutoff_state(
                         self.params.cutoff)

    def pack(self):
        return list(pack(self.params.plant, self.params.model)) + self.cutoff_pack()

    def cutoff_pack(self) -> list[float]:
        """The cut-off's setting, its gain (the full current range over its band), its
        lead."""
        cut, plant = self.params.cutoff, self.params.plant
        return [cut.p_set, 2.0 * plant.spool.I_max / cut.band, cut.lead]

    def pressure_cap(self, u):
        """A pump with a cut-off makes no more than its setting and band."""
        cut = self.params.cutoff
        return cut.p_set + cut.band if cut.p_set > 0.0 else None

    def static_values(self):
        """Eq. 10: the spool and the plate's inertia quasi-static (the paper's simplified
        model, keeping K_c)."""
        return {'model': 'simplified_Kc'}

    def dither_frequency(self):
        inp = self.params.plant.input
        return inp.dither_freq if inp.dither_amp > 0.0 else 0.0

    def steady_pack(self):
        return list(pack(self.params.plant.replace({'input.dither_amp': 0.0}),
                         self.params.model)) + self.cutoff_pack()

    def input_default(self, spec):
        plant = self.params.plant
        return plant.I_nominal if spec.name == 'current' else plant.pump.f_p

    def initial_state(self, P, u):
        """The pump at rest with ``x_c = 0`` (eq. 10) at its port's pressure."""
        plant = self.params.plant
        sp = plant.spool
        i_s = u['current'] - plant.I_nominal
        x_a = float(np.clip(sp.phi_s * i_s / sp.K_a, -plant.x_a_stop, plant.x_a_stop))
        if self.params.model != 'fine':
            return np.array([x_a])
        P_l = P['out']
        x_c = (sp.phi_s * i_s - sp.K_a * x_a) / (sp.K_a + sp.K_c)
        P_a = plant.actuator.P_a_bar - (plant.plate.K_b * x_a + sp.K_a * (x_a + x_c)
                                        + (P_l - plant.line.P_l_bar) * plant.plate.S_d
                                        ) / plant.actuator.S_a
        P_a = min(max(P_a, plant.fluid.P_T), max(P_l, plant.fluid.P_T))
        x = [x_c, 0.0, x_a, 0.0, P_a]
        if plant.input.tau_s > 0.0:
            x.append(i_s)
        return np.array(x + [P_l] * len(cutoff_state(self.params.cutoff)))
