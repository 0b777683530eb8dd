"""Typed, range-checked plant parameters (one schema, one loader).

The schema is dataclass field metadata: every parameter has a unit, a description and an
accepted range. ``config/pump.yaml`` holds the values. Loading validates everything at once and
raises :class:`ParamError` with one line per bad value, so that a user sees every mistake in one
go and never a traceback.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
import dataclasses
from dataclasses import dataclass
import math
from pathlib import Path
from typing import Any

import numpy as np

from .schema import (
    build,
    check_value,
    fmt,
    group,
    must_exceed,
    ParamError,
    ParamSpec,
    read_params_file,
    spec,
    spec_map,
    specs_of,
    to_flat,
)

__all__ = ['INPUTS', 'Params', 'ParamError', 'check_input', 'default_params_path', 'input_spec',
           'iter_specs', 'load_params', 'params_from_dict']


@dataclass(frozen=True)
class Fluid:
    rho: float = spec('kg/m^3', 'oil density', 600.0, 1200.0)
    beta: float = spec('Pa', 'effective bulk modulus of the oil (1/beta is the compressibility)',
                       1.0e8, 3.0e9)
    nu: float = spec('m^2/s', 'kinematic viscosity (documents dp_cr; not in the equations)',
                     1.0e-7, 1.0e-3)
    alpha_air: float = spec('-', 'entrained air volume fraction at p_atm; 0 = pure liquid',
                            0.0, 0.2)
    p_atm: float = spec('Pa', 'atmospheric pressure (absolute), for the air and floor models',
                        5.0e4, 1.2e5)
    P_T: float = spec('Pa', 'tank pressure (gauge) at the pilot valve outlet edge', 0.0, 5.0e6)
    pressure_floor: bool = spec('-', 'stop pressures at absolute zero (cavitation floor)',
                                default=True)
    dp_floor: float = spec('Pa', 'width of the smooth pressure floor above absolute zero',
                           1.0e2, 1.0e5, default=1.0e4)


@dataclass(frozen=True)
class Pump:
    V_p: float = spec('m^3/rev', 'maximum displacement', 1.0e-6, 1.0e-3)
    f_p: float = spec('Hz', 'shaft frequency in rev/s (eq. 8)', 1.0, 100.0, live=True)
    flow_map: str = spec('-', 'eq. 8 reading: paper (literal) or consistent (full stroke)',
                         choices=('paper', 'consistent'))
    x_a_max: float = spec('m', 'stroke normaliser of eq. 8', 1.0e-3, 0.1)
    l_d: float = spec('m', 'actuator arm of eq. 5 (information only)', 1.0e-3, 1.0)
    disp_clip: bool = spec('-', 'clip the displacement fraction to [0, 1]')


@dataclass(frozen=True)
class Spool:
    m_c: float = spec('kg', 'spool and armature moving mass (eq. 1)', 1.0e-4, 1.0)
    K_c: float = spec('N/m', 'spool bias spring stiffness (eq. 1)', 1.0, 1.0e6)
    K_a: float = spec('N/m', 'feedback spring stiffness between spool and actuator', 10.0, 1.0e6)
    phi_s: float = spec('N/A', 'solenoid force constant (eq. 1)', 1.0, 1.0e4)
    I_max: float = spec('A', 'half-width of the regulating current range (eq. 2)', 0.01, 5.0)
    I_min: float = spec('A', 'start of the regulating current range (eq. 2)', 1.0e-3, 5.0)
    x_c_max: float = spec('m', 'spool stroke limit', 1.0e-4, 0.02)
    c_c: float = spec('N s/m', 'viscous part of A_c', 0.0, 1.0e4)
    F_coul_c: float = spec('N', 'Coulomb part of A_c; 0 = no friction', 0.0, 100.0)
    v_eps_c: float = spec('m/s', 'tanh smoothing velocity of the Coulomb term', 1.0e-7, 1.0)
    k_stop_c: float = spec('N/m', 'spool end-stop stiffness; 0 = no end stop', 0.0, 1.0e10)
    c_stop_c: float = spec('N s/m', 'spool end-stop damping', 0.0, 1.0e6)


@dataclass(frozen=True)
class Actuator:
    d_a: float = spec('m', 'control-piston diameter (S_a = pi d_a^2 / 4)', 1.0e-3, 0.2)
    S_a: float = spec('m^2', 'control-piston active area (eq. 3)', 1.0e-6, 1.0e-2)
    V_a0: float = spec('m^3', 'actuator chamber volume at x_a = 0', 1.0e-7, 1.0e-2)
    V_a_min: float = spec('m^3', 'lower bound of the actuator volume', 1.0e-8, 1.0e-2)
    P_a_bar: float = spec('Pa', 'actuator pressure at the bias-spring preload (eq. 7)',
                          1.0e5, 2.0e7)
    mu_a: float = spec('m^3/(s m Pa^0.5)', 'pilot orifice coefficient (eq. 4)', 1.0e-9, 1.0e-3)
    h_a: float = spec('m', 'equivalent orifice height, mu_a = h_a sqrt(2/rho) (eq. 4)',
                      1.0e-7, 1.0e-1)
    dp_cr_a: float = spec('Pa', 'laminar/turbulent transition of the pilot orifice; 0 = sqrt',
                          0.0, 1.0e6)
    G_leak_a: float = spec('m^3/(s Pa)', 'laminar leakage actuator to tank; 0 = none',
                           0.0, 1.0e-10)


@dataclass(frozen=True)
class Plate:
    m_a: float = spec('kg', 'plate and control-piston equivalent mass (eq. 6)', 1.0e-3, 100.0)
    K_b: float = spec('N/m', 'bias (swash-plate return) spring stiffness', 1.0, 1.0e8)
    S_d: float = spec('m^2', 'equivalent area of line pressure on the plate', 0.0, 1.0e-2)
    c_a: float = spec('N s/m', 'viscous part of A_a', 0.0, 1.0e6)
    F_coul_a: float = spec('N', 'Coulomb part of A_a; 0 = no friction', 0.0, 1.0e4)
    v_eps_a: float = spec('m/s', 'tanh smoothing velocity of the Coulomb term', 1.0e-7, 1.0)
    k_stop_a: float = spec('N/m', 'swash-plate end-stop stiffness; 0 = no end stop', 0.0, 1.0e10)
    c_stop_a: float = spec('N s/m', 'swash-plate end-stop damping', 0.0, 1.0e7)


@dataclass(frozen=True)
class Line:
    V_l: float = spec('m^3', 'line (pump outlet and hose) volume (eq. 9)', 1.0e-6, 0.1)
    P_l_bar: float = spec('Pa', 'line pressure at the bias-spring preload (eq. 7)', 1.0e5, 4.5e7)
    # A load pressure below 0.1 bar gauge is almost always a value typed in bar.
    P_u: float = spec('Pa', 'load pressure downstream of the load orifice (eq. 9)',
                      1.0e4, 4.5e7, live=True)
    xi_u: float = spec('-', 'load aperture degree (eq. 9)', 0.0, 1.0, live=True)
    gamma_u: float = spec('-', 'load law exponent: 2 turbulent, 1 laminar (eq. 9)', 1.0, 2.0)
    mu_u: float = spec('m^3/(s Pa^(1/gamma_u))', 'load orifice coefficient (eq. 9)',
                       1.0e-12, 1.0e-2)
    dp_cr_u: float = spec('Pa', 'laminar/turbulent transition of the load orifice; 0 = root',
                          0.0, 1.0e6)


@dataclass(frozen=True)
class Relief:
    enabled: bool = spec('-', 'relief valve of Fig. 1 on the line')
    p_crack: float = spec('Pa', 'cracking pressure (gauge)', 1.0e6, 5.0e7)
    p_full: float = spec('Pa', 'fully-open pressure (gauge)', 1.0e6, 5.0e7)
    q_full: float = spec('m^3/s', 'flow at p_full', 1.0e-6, 0.1)


@dataclass(frozen=True)
class Input:
    dither_amp: float = spec('A', 'sinusoidal dither amplitude on the solenoid current', 0.0, 1.0)
    dither_freq: float = spec('Hz', 'dither frequency', 1.0, 5000.0)
    tau_s: float = spec('s', 'first-order solenoid current lag; 0 = ideal current source',
                        0.0, 0.1, default=0.0)


# Relative tolerance for the redundant pairs and design condition D1.
REL_TOL = 1.0e-3


@dataclass(frozen=True)
class Params:
    """The validated plant parameter set, SI units, gauge pressures (tank = 0 Pa)."""

    fluid: Fluid = group()
    pump: Pump = group()
    spool: Spool = group()
    actuator: Actuator = group()
    plate: Plate = group()
    line: Line = group()
    relief: Relief = group()
    input: Input = group()

    # Derived quantities, named as in the paper.
    @property
    def Q_max(self) -> float:
        """Full-displacement flow ``V_p f_p`` [m^3/s] at the nominal shaft speed."""
        return self.pump.V_p * self.pump.f_p

    @property
    def stroke_scale(self) -> float:
        """``x_a`` change per unit displacement fraction [m] (eq. 8 and its I1 reading)."""
        return self.pump.x_a_max if self.pump.flow_map == 'paper' else 2.0 * self.pump.x_a_max

    @property
    def x_a_stop(self) -> float:
        """Physical stroke limit of the plate [m]: 0..100 % displacement (docs/reference.md I1)."""
        return 0.5 * self.stroke_scale

    @property
    def b_p(self) -> float:
        """``b_p = V_p f_p / x_a_max`` [m^2/s] of eq. 13 (halved for the consistent map)."""
        return self.Q_max / self.stroke_scale

    @property
    def i_full(self) -> float:
        """Current variation ``i_s`` [A] from 50 % to 100 % displacement."""
        return self.spool.K_a * self.x_a_stop / self.spool.phi_s

    @property
    def I_nominal(self) -> float:
        """Absolute current at 50 % displacement, ``I_min + I_max`` [A] (eq. 2, i_s = 0)."""
        return self.spool.I_min + self.spool.I_max

    @property
    def current_range(self) -> tuple[float, float]:
        """Absolute current [A] for 0 % and 100 % displacement."""
        return (self.I_nominal - self.i_full, self.I_nominal + self.i_full)

    @property
    def I_limits(self) -> tuple[float, float]:
        """Absolute current range of eq. 2 [A]: ``[I_min, I_min + 2 I_max]``."""
        return (self.spool.I_min, self.spool.I_min + 2.0 * self.spool.I_max)

    def replace(self, values: Mapping[str, Any]) -> Params:
        """Return a re-validated copy with dotted keys (``'line.xi_u'``) replaced."""
        data = self.flat()
        data.update(values)
        return params_from_dict(data)

    def to_dict(self) -> dict[str, dict[str, Any]]:
        """Nested ``{group: {name: value}}`` dictionary."""
        return {f.name: dataclasses.asdict(getattr(self, f.name))
                for f in dataclasses.fields(self)}

    def flat(self) -> dict[str, Any]:
        """Flat ``{'group.name': value}`` dictionary (ROS parameter names)."""
        return to_flat(self)

    def cross_checks(self) -> list[str]:
        """Relations between parameters that single ranges cannot express."""
        return _cross_checks(self)


def iter_specs() -> Iterator[ParamSpec]:
    """Every plant parameter of the schema, in file order."""
    return iter(specs_of(Params))


# The operating-point inputs of the model and the plant parameters whose ranges they share.
INPUTS = {'load_pressure': 'line.P_u', 'aperture': 'line.xi_u', 'shaft_speed': 'pump.f_p'}


def input_spec(name: str) -> ParamSpec:
    """The schema entry of an operating-point input (``load_pressure``, ``aperture``,
    ``shaft_speed``): its plant parameter's unit, range and description."""
    return dataclasses.replace(spec_map(Params)[INPUTS[name]], name=name)


def check_input(name: str, values, t=None) -> str | None:
    """The first value of an input signal outside its accepted range, as one line naming
    the value, the time and the range (with a unit hint); ``None`` when all are inside."""
    s = input_spec(name)
    v = np.atleast_1d(np.asarray(values, dtype=float))
    lo, hi = s.range
    bad = ~np.isfinite(v) | (v < lo) | (v > hi)
    if not bad.any():
        return None
    k = int(np.flatnonzero(bad)[0])
    _, err = check_value(s, float(v[k]))
    if t is not None:
        tk = float(np.atleast_1d(t)[k])
        head, sep, tail = err.partition(': ')
        err = f'{head} at t = {fmt(tk)} s{sep}{tail}'

    return err


def _cross_checks(p: Params) -> list[str]:
    """Relations between parameters that single ranges cannot express."""
    out = []
    sp, ac = p.spool, p.actuator

    def rel(a: float, b: float) -> float:
        return abs(a - b) / max(abs(a), abs(b), 1e-300)

    lhs, rhs = sp.phi_s * sp.I_max, sp.K_a * p.pump.x_a_max
    if rel(lhs, rhs) > REL_TOL:
        out.append(f'design condition D1 violated: phi_s*I_max = {fmt(sp.phi_s)} N/A * '
                   f'{fmt(sp.I_max)} A = {fmt(lhs)} N but K_a*x_a_max = {fmt(sp.K_a)} N/m * '
                   f'{fmt(p.pump.x_a_max)} m = {fmt(rhs)} N (must be equal within '
                   f'{REL_TOL:.0e}, else eq. 11 does not hold)')
    s_a = math.pi * ac.d_a ** 2 / 4.0
    if rel(ac.S_a, s_a) > REL_TOL:
        out.append(f'actuator.S_a = {fmt(ac.S_a)} m^2 disagrees with pi*d_a^2/4 = {fmt(s_a)} '
                   f'm^2 (d_a = {fmt(ac.d_a)} m): change both')
    mu = ac.h_a * math.sqrt(2.0 / p.fluid.rho)
    if rel(ac.mu_a, mu) > REL_TOL:
        out.append(f'actuator.mu_a = {fmt(ac.mu_a)} disagrees with h_a*sqrt(2/rho) = {fmt(mu)}'
                   f' (eq. 4): change both')
    out += must_exceed('relief.p_full', p.relief.p_full, 'relief.p_crack', p.relief.p_crack)
    if ac.P_a_bar >= p.line.P_l_bar:
        out.append(f'actuator.P_a_bar = {fmt(ac.P_a_bar)} Pa must be below line.P_l_bar = '
                   f'{fmt(p.line.P_l_bar)} Pa (the pilot valve feeds the actuator from the line)')
    v_min = ac.V_a0 - ac.S_a * p.x_a_stop
    if v_min <= ac.V_a_min:
        out.append(f'actuator.V_a0 = {fmt(ac.V_a0)} m^3 leaves {fmt(v_min)} m^3 at full stroke,'
                   f' not above actuator.V_a_min = {fmt(ac.V_a_min)} m^3')
    if p.i_full > sp.I_max * (1.0 + REL_TOL):
        out.append(f'full displacement needs i_s = {fmt(p.i_full)} A beyond I_max = '
                   f'{fmt(sp.I_max)} A (eq. 2)')
    return out


def params_from_dict(data: Mapping[str, Any], source: str | None = None) -> Params:
    """Validate a nested or dotted mapping and build :class:`Params`.

    Raises
    ------
    ParamError
        With one line per unknown, missing or bad value, then per violated relation.
    """
    return build(Params, data, source)


def load_params(path: str | Path) -> Params:
    """Load and validate plant parameters from a params file such as ``config/pump.yaml``.

    Both a ROS 2 params file (``/**: ros__parameters:``) and a plain ``{group: {key: value}}``
    file are accepted. Values are SI, pressures gauge.

    Raises
    ------
    ParamError
        With one line per problem (unknown key, missing key, non-number, out of range, D1).
    """
    return params_from_dict(read_params_file(path), source=str(path))


def default_params_path() -> Path:
    """The reference plant file: ``$HYDROPUMP_PARAMS``, the source tree's ``config/pump.yaml``,
    or the copy installed with ``hydropump_bringup`` (found through ``AMENT_PREFIX_PATH`` or the
    Python prefix, without importing ROS)."""
    import os
    import sys
    env = os.environ.get('HYDROPUMP_PARAMS')
    if env:
        return Path(env)
    here = Path(__file__).resolve()
    candidates = [here.parents[2] / 'config' / 'pump.yaml']
    prefixes = [p for p in os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep) if p]
    for prefix in prefixes + [sys.prefix]:
        candidates.append(Path(prefix) / 'share' / 'hydropump_bringup' / 'config' / 'pump.yaml')
    for cand in candidates:
        if cand.is_file():
            return cand
    raise ParamError(['no parameter file found: pass one, or set HYDROPUMP_PARAMS'])
