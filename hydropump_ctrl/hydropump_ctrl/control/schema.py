"""Typed, range-checked controller parameters: one schema for the library, the design tool and
the future ROS parameter bridge.

The schema is :mod:`hydropump_sim.schema`'s: dataclass field metadata made with
:func:`~hydropump_sim.schema.spec` (unit, description, range or choices, default, ``live``),
and every value is checked by :func:`~hydropump_sim.schema.check_value`, so a bad value gives
one line such as ``emc.tau_control = 0 s: outside the accepted range [0.001, 5] s (...)``.

Parameter names are dotted snake_case groups, SI units, the paper's symbols inside the
``model`` group. ``live`` parameters (gains, eigenvalues, limits, references, mode, excitation)
may change while the controller runs; the others are read-only in a ROS node because they fix
the embedded model's structure (delay line length, update period).

The file format is a ROS 2 params file (``/**: ros__parameters:``), as ``config/controller.yaml``
written by ``hydropump design``.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
import dataclasses
from dataclasses import dataclass
import math
from pathlib import Path
from typing import Any

from hydropump_sim.measure import FEEDBACK_FLOW_SIGNALS, LINE_FLOW_SIGNAL
from hydropump_sim.schema import (
    build,
    group,
    ParamError,
    ParamSpec,
    read_params_file,
    spec,
    spec_map,
    specs_of,
    to_flat,
    unknown_key_line,
)
from hydropump_sim.schema import (
    dump_ros_yaml as _dump,
)

MODES = ('flow', 'margin', 'open_loop')
ALGORITHMS = ('emc', 'pi')
ANTIWINDUP = ('none', 'back_calculation', 'conditional_integration')
EXCITATIONS = ('staircase', 'prbs', 'chirp', 'sine')


@dataclass(frozen=True)
class General:
    """Group ``controller``: which law runs, in which mode, how fast."""

    algorithm: str = spec('-', 'control law: emc (Embedded Model Control) or pi (baseline); '
                          'live in the node: the new law starts bumplessly from the present '
                          'command', choices=ALGORITHMS, default='emc', live=True)
    mode: str = spec('-', 'mode: flow (track a flow reference), margin (load sensing: regulate '
                     'P_l - P_u) or open_loop (identification excitation)', choices=MODES,
                     default='flow', live=True)
    update_rate: float = spec('Hz', 'nominal update rate; the embedded model is discretised '
                              'at its period', 10.0, 2000.0, default=200.0)
    flow_signal: str = spec('-', 'flow measurement used for feedback: line_flow (q_l, the '
                            'output of eqs. 14-16) or pump_flow (Q_p)',
                            choices=FEEDBACK_FLOW_SIGNALS, default=LINE_FLOW_SIGNAL)


@dataclass(frozen=True)
class Limits:
    """Group ``limits``: what every command obeys, whatever the law and the mode."""

    current_min: float = spec('A', 'lowest absolute solenoid current command (inside eq. 2)',
                              0.0, 5.0, default=0.1, live=True)
    current_max: float = spec('A', 'highest absolute solenoid current command (inside eq. 2)',
                              0.0, 5.0, default=0.9, live=True)
    rate_limit: float = spec('A/s', 'largest command slew rate', 0.01, 1000.0, default=20.0,
                             live=True)
    safe_current: float = spec('A', 'command before the first update and when the '
                               'measurements are lost (0.3 A: zero displacement)', 0.0, 5.0,
                               default=0.3, live=True)
    measurement_timeout: float = spec('s', 'time without a valid measurement after which the '
                                      'command ramps to safe_current', 0.0, 10.0,
                                      default=0.1, live=True)


@dataclass(frozen=True)
class Reference:
    """Group ``reference``: the set-points of the closed-loop modes."""

    flow: float = spec('m^3/s', 'flow reference of flow mode', 0.0, 1.0e-2,
                       default=5.625e-4, live=True)
    margin: float = spec('Pa', 'margin set-point P_l - P_u of margin mode (load sensing)',
                         1.0e5, 1.0e7, default=2.5e6, live=True)


@dataclass(frozen=True)
class Model:
    """Group ``model``: the embedded model, written by ``hydropump design``.

    The current-to-flow path is eq. 19 (identified ``G0``, ``tau``, ``t_d``) with the
    simplified model's structure around it (eqs. 10-13, 15, 17): the spool stroke limit, the
    faster falling-flow branch with its zero, the end stops and the line capacitance.
    """

    gain: float = spec('m^3/(s A)', 'flow per current, eq. 19 G0 in SI: '
                       'G0/100 * V_p f_p / I_max (eq. 11)', 1.0e-6, 1.0)
    I_nominal: float = spec('A', 'absolute current of the mean flow Q_bar (eq. 2, i_s = 0)',
                            0.0, 5.0)
    I_max: float = spec('A', 'half-width of the current range of eq. 2: commands stay in '
                        'I_nominal +- I_max', 0.01, 5.0)
    Q_bar: float = spec('m^3/s', 'mean flow at I_nominal (eq. 8)', 0.0, 1.0e-2)
    Q_max: float = spec('m^3/s', 'full-displacement flow V_p f_p (the end stop)', 1.0e-6,
                        1.0e-2)
    tau: float = spec('s', 'time constant for growing flow (eq. 19, x_c > 0)', 1.0e-3, 10.0)
    tau_down: float = spec('s', 'time constant for falling flow (eq. 15, x_c < 0)', 1.0e-3,
                           10.0)
    tau_z: float = spec('s', 'zero of eq. 17 for falling flow, S_a/b_p; 0 = none', 0.0, 1.0)
    t_d: float = spec('s', 'flow measurement delay (eq. 19)', 0.0, 2.0)
    flow_error_max: float = spec('m^3/s', 'spool stroke limit as a flow error, b_p x_c_max '
                                 '(eq. 10)', 1.0e-7, 1.0e-2)
    C_l: float = spec('m^3/Pa', 'line capacitance V_l/beta (eq. 9)', 1.0e-16, 1.0e-8)
    gamma_u: float = spec('-', 'load law exponent of eq. 9', 1.0, 2.0)
    load_law: str = spec('-', 'what the margin loop sees downstream: orifice (eq. 9, the '
                         "paper's load: its flow grows with the margin) or compensated (a "
                         "load-sensing circuit's compensated sections: their flow does not)",
                         choices=('orifice', 'compensated'), default='orifice')
    dp_compensator: float = spec('Pa', "the compensators' setting, as the compensated margin "
                                 'loop models it: below it a compensated load starves and '
                                 'takes flow as an orifice does (its flow grows with the '
                                 'square root of the margin); 0 = fed at any margin', 0.0,
                                 1.0e8, default=0.0)
    relief_crack: float = spec('Pa', 'cracking pressure of the relief valve at the pump '
                               'outlet, as the compensated margin loop models it (its flow '
                               'is not a load to feed); 0 = none', 0.0, 1.0e9, default=0.0)
    relief_full: float = spec('Pa', 'pressure at which that relief valve is fully open', 0.0,
                              1.0e9, default=0.0)
    relief_q_full: float = spec('m^3/s', 'flow of that relief valve fully open', 0.0, 1.0,
                                default=0.0)


@dataclass(frozen=True)
class Emc:
    """Group ``emc``: the closed-loop eigenvalues of Embedded Model Control, as time constants.

    All gains follow from these by pole placement on the embedded model (see
    :mod:`hydropump_ctrl.control.design`).
    """

    tau_reference: float = spec('s', 'reference generator eigenvalue (flow trajectory)',
                                1.0e-3, 5.0, default=0.025, live=True)
    reference_headroom: float = spec('-', 'fraction of the spool stroke limit the reference '
                                     'trajectory may use', 0.05, 1.0, default=1.0, live=True)
    tau_control: float = spec('s', 'state-feedback eigenvalue (tracking error)', 1.0e-3, 5.0,
                              default=0.015, live=True)
    tau_estimator_fast: float = spec('s', 'faster noise-estimator eigenvalue (flow state and '
                                     'disturbance)', 1.0e-3, 5.0, default=0.035, live=True)
    tau_estimator_slow: float = spec('s', 'slower noise-estimator eigenvalue (flow state and '
                                     'disturbance)', 1.0e-3, 5.0, default=0.06, live=True)
    disturbance_max: float = spec('m^3/s', 'bound of the disturbance estimate (anti-windup)',
                                  0.0, 1.0e-2, default=3.0e-4, live=True)
    tau_margin_reference: float = spec('s', 'margin set-point trajectory eigenvalue', 1.0e-3,
                                       5.0, default=0.04, live=True)
    tau_margin_flow: float = spec('s', 'reference generator eigenvalue of the flow trajectory '
                                  'in margin mode (load-conductance cancellation)', 1.0e-3, 5.0,
                                  default=0.01, live=True)
    tau_line_fast: float = spec('s', 'faster line-estimator eigenvalue (margin and load '
                                'conductance)', 1.0e-3, 5.0, default=0.005, live=True)
    tau_line_slow: float = spec('s', 'slower line-estimator eigenvalue (margin and load '
                                'conductance)', 1.0e-3, 5.0, default=0.008, live=True)
    tau_margin_loop: float = spec('s', 'margin eigenvalue against compensated loads '
                                  '(model.load_law compensated): the line capacitance is '
                                  'filled or drained toward the margin trajectory at this rate',
                                  1.0e-3, 5.0, default=0.04, live=True)


def _pi_fields(unit_e: str, what: str, p: float, i: float, ff: float, ref_tau: float,
               ref_tau_down: float, ref_delay: float, p_hi: float, i_hi: float):
    """Field specs of one PI group; units follow the controlled variable."""
    d_unit = f'A s/{unit_e}'
    return {
        'p': spec(f'A/{unit_e}', f'proportional gain on the {what} error', 0.0, p_hi,
                  default=p, live=True),
        'i': spec(f'A/({unit_e} s)', f'integral gain on the {what} error', 0.0, i_hi,
                  default=i, live=True),
        'd': spec(d_unit, f'derivative gain on the {what} error', 0.0, p_hi, default=0.0,
                  live=True),
        'i_clamp_max': spec('A', 'upper clamp of the integral term', -5.0, 5.0, default=0.8,
                            live=True),
        'i_clamp_min': spec('A', 'lower clamp of the integral term', -5.0, 5.0, default=-0.8,
                            live=True),
        'u_clamp_max': spec('A', 'upper clamp of the PI command (absolute current)', 0.0, 5.0,
                            default=0.9, live=True),
        'u_clamp_min': spec('A', 'lower clamp of the PI command (absolute current)', 0.0, 5.0,
                            default=0.1, live=True),
        'feedforward_gain': spec('-', 'gain on the eq. 11 static-map feedforward', 0.0, 2.0,
                                 default=ff, live=True),
        'antiwindup_strategy': spec('-', 'none, back_calculation or conditional_integration',
                                    choices=ANTIWINDUP, default='back_calculation',
                                    live=True),
        'tracking_time_constant': spec('s', 'back-calculation tracking time constant; '
                                       '0 = p/i (control_toolbox default)', 0.0, 10.0,
                                       default=0.0, live=True),
        'error_deadband': spec(unit_e, 'no integration while |error| is below this', 0.0,
                               p_hi, default=0.0, live=True),
        'reference_tau': spec('s', 'time constant of the reference model the error is taken '
                              'from, rising; 0 = raw reference', 0.0, 5.0, default=ref_tau,
                              live=True),
        'reference_tau_down': spec('s', 'time constant of the reference model, falling',
                                   0.0, 5.0, default=ref_tau_down, live=True),
        'reference_delay': spec('s', 'delay of the reference model (the measurement delay); '
                                '0 = none', 0.0, 2.0, default=ref_delay, live=True),
    }


PiFlow = dataclasses.make_dataclass(
    'PiFlow', [(k, float if k != 'antiwindup_strategy' else str, f)
               for k, f in _pi_fields('(m^3/s)', 'flow', 309.0, 3090.0, 1.0, 0.1, 0.039, 0.055,
                                      1.0e5, 1.0e7).items()],
    frozen=True)
PiFlow.__module__ = __name__
PiFlow.__doc__ = """Group ``pi.flow``: the PI baseline in flow mode (control_toolbox names)."""
PiMargin = dataclasses.make_dataclass(
    'PiMargin', [(k, float if k != 'antiwindup_strategy' else str, f)
                 for k, f in _pi_fields('Pa', 'margin', 2.2e-8, 2.0e-7, 1.0, 0.04, 0.04, 0.0,
                                        1.0e-3, 1.0e-1).items()],
    frozen=True)
PiMargin.__module__ = __name__
PiMargin.__doc__ = """Group ``pi.margin``: the PI baseline in margin mode (load sensing)."""


@dataclass(frozen=True)
class Excitation:
    """Group ``excitation``: open-loop signals for identification experiments.

    Levels, offsets and amplitudes are in ``unit``: ``percent`` of displacement (through the
    eq. 11 static map of the ``model`` group) or ``A`` (absolute current for levels and
    offsets, current change for amplitudes).
    """

    signal: str = spec('-', 'staircase, prbs, chirp or sine', choices=EXCITATIONS,
                       default='staircase', live=True)
    unit: str = spec('-', 'unit of levels, offset and amplitude: percent (of displacement) '
                     'or A', choices=('percent', 'A'), default='percent', live=True)
    offset: float = spec('percent or A', 'operating point of prbs, chirp and sine (a shift '
                         'from the present command if relative)', -100.0, 100.0, default=50.0,
                         live=True)
    relative: bool = spec('-', 'prbs, chirp and sine around the command at the start of the '
                          'experiment plus offset (bumpless entry); staircase levels stay '
                          'absolute', default=False, live=True)
    amplitude: float = spec('percent or A', 'step height (staircase) or amplitude', 0.0, 100.0,
                            default=10.0, live=True)
    levels_min: float = spec('percent or A', 'lowest staircase operating point', 0.0, 100.0,
                             default=20.0, live=True)
    levels_max: float = spec('percent or A', 'highest staircase operating point', 0.0, 100.0,
                             default=80.0, live=True)
    n_levels: int = spec('-', 'number of staircase operating points', 1, 100, default=4,
                         live=True)
    direction: str = spec('-', 'staircase steps: both (up and down around each level) or up '
                          '(levels_min to levels_max, growing flow only, as the paper '
                          'identifies)', choices=('both', 'up'), default='both', live=True)
    dwell: float = spec('s', 'duration of one stair', 0.01, 100.0, default=1.0, live=True)
    bit_time: float = spec('s', 'PRBS bit duration', 1.0e-3, 10.0, default=0.05, live=True)
    prbs_order: int = spec('-', 'PRBS shift-register length n (period 2^n - 1 bits)', 3, 20,
                           default=9, live=True)
    f_start: float = spec('Hz', 'chirp start frequency', 1.0e-3, 100.0, default=0.2,
                          live=True)
    f_end: float = spec('Hz', 'chirp end frequency', 1.0e-3, 100.0, default=20.0, live=True)
    sweep_time: float = spec('s', 'chirp duration', 0.01, 1000.0, default=20.0, live=True)
    sweep: str = spec('-', 'chirp law', choices=('logarithmic', 'linear'),
                      default='logarithmic', live=True)
    frequency: float = spec('Hz', 'sine frequency', 1.0e-3, 100.0, default=1.0, live=True)
    seed: int = spec('-', 'seed of the random parts (PRBS register, staircase order)', 0,
                     2 ** 31 - 1, default=0, live=True)
    repeat: bool = spec('-', 'start again at the end (otherwise hold the last value)',
                        default=True, live=True)


def iter_specs() -> Iterator[ParamSpec]:
    """Every controller parameter of the schema (ROS names, SI units) in file order."""
    return iter(specs_of(ControllerConfig))


def specs() -> dict[str, ParamSpec]:
    """Schema entries by name."""
    return spec_map(ControllerConfig)


@dataclass(frozen=True)
class ControllerConfig:
    """The validated controller configuration (SI units).

    Build it with :func:`config_from_dict` or :func:`load_config`; change it with
    :meth:`replace`, which re-validates everything and raises :class:`ParamError`.
    """

    controller: General = group()
    limits: Limits = group()
    reference: Reference = group()
    model: Model = group()
    emc: Emc = group()
    pi_flow: PiFlow = group('pi.flow')
    pi_margin: PiMargin = group('pi.margin')
    excitation: Excitation = group()

    @property
    def period(self) -> float:
        """Nominal update period [s]."""
        return 1.0 / self.controller.update_rate

    @property
    def delay_steps(self) -> int:
        """Measurement delay of the embedded model in whole update periods (at least one: the
        sample of ``t_k`` is compared with the model driven by the command of ``t_k-1``)."""
        return max(1, int(round(self.model.t_d / self.period)))

    def bandwidth(self, mode: str | None = None) -> float:
        """The control bandwidth [Hz] of ``mode`` (default: the faster of flow and margin
        mode): ``1/(2 pi tau)`` of its fastest state-feedback or reference eigenvalue, the
        fastest dynamics the loop acts on (section IV's separation is judged against it)."""
        e = self.emc
        taus = {'flow': (e.tau_control, e.tau_reference),
                'margin': (e.tau_margin_flow, e.tau_margin_reference, e.tau_margin_loop)}
        use = taus.get(mode, (*taus['flow'], *taus['margin']))
        return 1.0 / (2.0 * math.pi * min(use))

    def group(self, name: str):
        """Group object by its parameter prefix (``'pi.flow'`` -> ``pi_flow``)."""
        return getattr(self, name.replace('.', '_'))

    def flat(self) -> dict[str, Any]:
        """Flat ``{'group.name': value}`` dictionary (ROS parameter names)."""
        return to_flat(self)

    def replace(self, values: Mapping[str, Any]) -> ControllerConfig:
        """Return a re-validated copy with dotted keys replaced (one line per problem)."""
        data = self.flat()
        data.update(values)
        return config_from_dict(data)

    def to_ros_yaml(self, header: str = '') -> str:
        """The configuration as a ROS 2 params file (``/**: ros__parameters:``)."""
        return dump_ros_yaml(self.flat(), header)


def _cross_checks(c: ControllerConfig, lo_hi: tuple[float, float] | None) -> list[str]:
    """Relations between parameters that single ranges cannot express."""
    out = []
    lim, m, e = c.limits, c.model, c.emc
    if lim.current_min >= lim.current_max:
        out.append(f'limits.current_min = {lim.current_min:g} A must be below '
                   f'limits.current_max = {lim.current_max:g} A')
    if not lim.current_min <= lim.safe_current <= lim.current_max:
        out.append(f'limits.safe_current = {lim.safe_current:g} A is outside '
                   f'[limits.current_min, limits.current_max] = [{lim.current_min:g}, '
                   f'{lim.current_max:g}] A')
    eq2 = (m.I_nominal - m.I_max, m.I_nominal + m.I_max)
    for lo, hi, what in ((*eq2, 'model.I_nominal +- model.I_max'),
                         *(((*lo_hi, 'the plant parameters'),) if lo_hi is not None else ())):
        if lim.current_min < lo - 1e-12 or lim.current_max > hi + 1e-12:
            out.append(f'limits.current_min/max = [{lim.current_min:g}, {lim.current_max:g}] A '
                       f'leave the current range of eq. 2, [{lo:g}, {hi:g}] A ({what})')
    if m.relief_crack > 0.0 and not (m.relief_full > m.relief_crack and m.relief_q_full > 0.0):
        out.append(f'model.relief_crack = {m.relief_crack:g} Pa: model.relief_full (now '
                   f'{m.relief_full:g} Pa) must lie above it and model.relief_q_full (now '
                   f'{m.relief_q_full:g} m^3/s) be positive')
    if m.Q_bar > m.Q_max:
        out.append(f'model.Q_bar = {m.Q_bar:g} m^3/s exceeds model.Q_max = {m.Q_max:g} m^3/s')
    if c.reference.flow > m.Q_max * 1.5:
        out.append(f'reference.flow = {c.reference.flow:g} m^3/s is more than 1.5 x model.Q_max'
                   f' = {m.Q_max:g} m^3/s (a value in L/min?)')
    T = c.period
    for name in ('tau_reference', 'tau_control', 'tau_estimator_fast', 'tau_estimator_slow',
                 'tau_margin_reference', 'tau_margin_flow', 'tau_line_fast', 'tau_line_slow'):
        v = getattr(e, name)
        if v < T:
            out.append(f'emc.{name} = {v:g} s is faster than the update period {T:g} s '
                       f'(an eigenvalue beyond the sampling cannot be placed reliably)')
    if e.tau_estimator_fast > e.tau_estimator_slow:
        out.append(f'emc.tau_estimator_fast = {e.tau_estimator_fast:g} s must not exceed '
                   f'emc.tau_estimator_slow = {e.tau_estimator_slow:g} s')
    if e.tau_line_fast > e.tau_line_slow:
        out.append(f'emc.tau_line_fast = {e.tau_line_fast:g} s must not exceed '
                   f'emc.tau_line_slow = {e.tau_line_slow:g} s')
    for g in ('pi.flow', 'pi.margin'):
        pg = c.group(g)
        if pg.i_clamp_min > pg.i_clamp_max:
            out.append(f'{g}.i_clamp_min = {pg.i_clamp_min:g} A exceeds {g}.i_clamp_max = '
                       f'{pg.i_clamp_max:g} A')
        if pg.u_clamp_min >= pg.u_clamp_max:
            out.append(f'{g}.u_clamp_min = {pg.u_clamp_min:g} A must be below {g}.u_clamp_max'
                       f' = {pg.u_clamp_max:g} A')
    x = c.excitation
    used = (('levels_min', 'levels_max', 'amplitude') if x.signal == 'staircase'
            else ('offset', 'amplitude'))
    if x.signal == 'staircase' and x.levels_min > x.levels_max:
        out.append(f'excitation.levels_min = {x.levels_min:g} exceeds excitation.levels_max = '
                   f'{x.levels_max:g}')
    top = 100.0 if x.unit == 'percent' else 5.0
    for name in used:
        if name == 'offset' and not x.relative and x.offset < 0.0:
            out.append(f'excitation.offset = {x.offset:g} is negative; only a relative '
                       'excitation may shift down')
        if getattr(x, name) > top:
            out.append(f'excitation.{name} = {getattr(x, name):g} is beyond {top:g} '
                       f'{"% of displacement" if x.unit == "percent" else "A"} '
                       f'(excitation.unit = {x.unit})')
    return out


def config_from_dict(data: Mapping[str, Any], source: str | None = None,
                     current_limits: tuple[float, float] | None = None) -> ControllerConfig:
    """Validate a nested or dotted mapping and build :class:`ControllerConfig`.

    Parameters
    ----------
    data : Mapping
        ``{'emc': {'tau_control': 0.03}, ...}`` or ``{'emc.tau_control': 0.03, ...}``.
    source : str, optional
        File name for the error header.
    current_limits : (float, float), optional
        The plant's current range of eq. 2 [A]; ``limits`` must lie inside it.

    Raises
    ------
    ParamError
        One line per unknown, missing or bad value, then per violated relation.
    """
    return build(ControllerConfig, data, source, what='controller parameter',
                 checks=lambda cfg: _cross_checks(cfg, current_limits))


def validate_parameter(config: ControllerConfig, name: str, value: Any) -> str | None:
    """One-line reason why setting ``name = value`` is refused, or ``None`` if it is accepted.

    This is what a ROS on-set-parameters callback needs: the value is checked against its
    range and against the rest of the configuration. Read-only parameters are refused.
    """
    s = specs().get(name)
    if s is None:
        return unknown_key_line(name, specs(), 'controller parameter')
    if not s.live:
        return f'{name} is read-only while the controller runs (it fixes the embedded model)'
    try:
        config.replace({name: value})
    except ParamError as exc:
        return exc.lines[0]
    return None


def load_config(path: str | Path, current_limits: tuple[float, float] | None = None
                ) -> ControllerConfig:
    """Load and validate a controller params file such as ``config/controller.yaml``.

    Raises
    ------
    ParamError
        With one line per problem.
    """
    return config_from_dict(read_params_file(path), source=str(path),
                            current_limits=current_limits)


def dump_ros_yaml(flat: Mapping[str, Any], header: str = '',
                  comments: Mapping[str, str] | None = None) -> str:
    """Write ``{'group.name': value}`` as a nested ROS 2 params file with unit comments."""
    return _dump(flat, header, comments, specs())
