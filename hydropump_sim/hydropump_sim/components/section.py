"""A load section of a load-sensing valve block (a composite), as a real machine's: a
proportional 4/3 valve (``valve_4_3``: meter-in and meter-out edges, closed centre, the
section's load-sensing signal from A or B by the spool's sign), a pressure compensator
before it (``pre``), after it (``post``, flow sharing) or none (a priority load, whose
priority valve compensates it), and the actuator it drives: a cylinder (double-acting when
its ``A_b`` is given, else single-acting with port B plugged) or a motor. Optional, as the
hardware has them:

- ``brake``: a counterbalance (brake, over-centre) valve in a work line (``brake_lines``:
  ``a``, ``b`` or ``both``), piloted by the other line, so that a hanging load or a
  swinging mass is held and driven down or braked under control, not by the spool's
  leakage;
- ``hose`` (and ``hose_b``, the B line's when it differs): the lines from the valve to the
  actuator (or to its brake valves), with their fluid's inertia and friction;
- ``relief``: port reliefs (each work line to tank, a cylinder's shock reliefs) or, for a
  motor, cross-port reliefs (each line to the other, a swing's);
- ``makeup``: anti-cavitation checks from tank into each work line.

Ports: ``supply``, ``tank``, ``load`` (the actuator's A side, which other components may
share), ``load_b`` (its B side; optional: a section node otherwise), ``sense`` (the
section's load-sensing signal, to the shuttle network) and ``ls`` (the load-sensing line,
for ``post``).

Wiring, by compensator:

- ``pre``: supply -> compensator (sensing the section's signal, a load-holding check in
  it) -> mid -> valve P; valve A/B -> the actuator;
- ``post`` (Rexroth's LUDV): supply -> valve P; valve A/B -> mid_a/mid_b -> a compensator
  on the load-sensing line -> the actuator, with a return check around each (the
  compensator is also the section's load-holding check); the section's signal is its load
  pressure, behind the compensator;
- ``none``: supply -> valve P; valve A/B -> the actuator.

Parameters: ``actuator``, ``compensator``, the volumes ``V_mid``, ``V_sense``, ``V_line``,
``makeup``, and the parts' own under ``valve.``, ``comp.``, ``cylinder.`` or ``motor.``,
``brake.`` (a counterbalance's), ``relief.`` (a relief's) and ``check.`` (the make-up
checks'). The section's inputs are ``command`` (the valve, -1..1: + drives A) and
``force`` or ``torque``; its signals ``flow`` (metered into A, net of what A returns),
``pressure`` (the actuator's A side), ``pressure_b``, ``opening`` (the spool), and
``position`` and ``velocity``, or ``speed`` and ``angle``. Every part's own inputs and
signals stay reachable by their full names (``boom.comp.opening``).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from ..schema import build, ParamError, spec, unknown_key_line
from .base import Component, Expansion, InputSpec, PortSpec, SignalSpec

GROUPS = ('valve', 'comp', 'cylinder', 'motor', 'brake', 'relief', 'check', 'hose', 'hose_b')
OWN = ('actuator', 'compensator', 'V_mid', 'V_sense', 'V_line', 'makeup', 'brake_lines')


@dataclass(frozen=True)
class SectionOptions:
    actuator: str = spec('-', 'what the section drives', choices=('cylinder', 'motor'))
    compensator: str = spec('-', 'pressure compensator: pre (before the valve), post (after '
                            'it, flow sharing) or none', choices=('pre', 'post', 'none'),
                            default='pre')
    V_mid: float = spec('m^3', 'volume between compensator and valve (each, post)', 1.0e-9,
                        1.0e-2, default=1.0e-5)
    V_sense: float = spec('m^3', 'volume of the load-sensing signal passage', 1.0e-9, 1.0e-3,
                          default=1.0e-6)
    V_line: float = spec('m^3', 'volume of a work line between valve and brake valve', 1.0e-9,
                         1.0e-2, default=1.0e-4)
    makeup: bool = spec('-', 'anti-cavitation checks from tank into each work line',
                        default=False)
    brake_lines: str = spec('-', 'the work lines with a brake (counterbalance) valve, if '
                            'brake.* is given', choices=('a', 'b', 'both'), default='both')


@dataclass(frozen=True)
class SectionSetup:
    options: SectionOptions
    parts: dict[str, dict[str, Any]]


class Section(Component):
    kind = 'section'
    doc = 'load section: 4/3 valve, pre/post/no compensator, cylinder or motor, brake valves'
    PORTS = (PortSpec('supply', 'pressure supply'), PortSpec('tank', 'return'),
             PortSpec('load', "the actuator's A side"),
             PortSpec('load_b', "the actuator's B side (a section node if not given)",
                      optional=True),
             PortSpec('sense', "the section's load-sensing signal: A or B while the valve "
                      'is open, tank while it is closed', optional=True),
             PortSpec('ls', 'load-sensing line (post-compensated sections)', optional=True))
    INPUTS = (InputSpec('command', '-', 'valve command -1..1 (+ drives A)', -1.0, 1.0, 0.0),
              InputSpec('force', 'N', 'cylinder: external force', -1.0e7, 1.0e7, 0.0),
              InputSpec('torque', 'N m', 'motor: load torque', -1.0e6, 1.0e6, 0.0))
    SIGNALS = (SignalSpec('flow', 'm^3/s', 'metered flow into the A side'),
               SignalSpec('pressure', 'Pa', 'load pressure, A side'),
               SignalSpec('pressure_b', 'Pa', 'load pressure, B side'),
               SignalSpec('opening', '-', 'valve spool, -1..1'),
               SignalSpec('position', 'm', 'cylinder position'),
               SignalSpec('velocity', 'm/s', 'cylinder velocity'),
               SignalSpec('speed', 'rad/s', 'motor speed'),
               SignalSpec('angle', 'rad', 'motor shaft angle'))

    @classmethod
    def build_params(cls, values: Mapping[str, Any], source: str | None = None):
        own: dict[str, Any] = {}
        parts: dict[str, dict[str, Any]] = {g: {} for g in GROUPS}
        for key, value in values.items():
            head, dot, rest = key.partition('.')
            if dot and head in parts:
                parts[head][rest] = value
            else:
                own[key] = value
        names = [f'{g}.' for g in GROUPS] + list(OWN)
        errors = [unknown_key_line(k, names) for k in own if k not in OWN]
        if errors:
            raise ParamError(errors, source)
        return SectionSetup(build(SectionOptions, own, source), parts)

    @classmethod
    def param_specs(cls):
        from ..schema import spec_map
        return spec_map(SectionOptions)

    def expand(self) -> Expansion:
        # One pass along the section's hydraulic path, from the actuator's lines to the
        # supply: each stage (brakes, hoses, compensator, valve, protection) connects to the
        # node names the stage before it chose, so it stays one function (long on purpose).
        o, parts, n = self.params.options, self.params.parts, self.name
        supply, tank, load = (self.ports[k][0] for k in ('supply', 'tank', 'load'))
        act = o.actuator
        other = 'motor' if act == 'cylinder' else 'cylinder'
        if parts[other]:
            raise ParamError([f'{n}: {other}.* given, but the actuator is a {act}'])
        if o.compensator == 'none' and parts['comp']:
            raise ParamError([f'{n}: comp.* given, but the section has no compensator'])
        two = act == 'motor' or float(parts['cylinder'].get('A_b', 0.0) or 0.0) > 0.0
        load_b = self.ports.get('load_b', [None])[0] or (f'{n}.b' if two else None)
        if load_b and not two:
            raise ParamError([f'{n}: port load_b is connected, but the cylinder is '
                              'single-acting (give cylinder.A_b)'])
        sense = self.ports.get('sense', [None])[0]
        out: list = []

        def vol(name, node, V):
            out.append((f'{n}.{name}', 'volume', {'V': V}, {'node': node}))
        # The actuator's lines, through brake valves when it has them, then hoses.
        a_side, b_side = load, load_b
        if parts['brake']:
            lines = {'a': ('a', 'both'), 'b': ('b', 'both')}
            va = f'{n}.va' if o.brake_lines in lines['a'] else load
            vb = (f'{n}.vb' if o.brake_lines in lines['b'] else load_b) if load_b else None
            if va != load:
                out.append((f'{n}.brake_a', 'counterbalance', parts['brake'],
                            {'load': load, 'valve': va, 'pilot': vb or tank}))
                vol('line_a', va, o.V_line)
            if vb is not None and vb != load_b:
                out.append((f'{n}.brake_b', 'counterbalance', parts['brake'],
                            {'load': load_b, 'valve': vb, 'pilot': va}))
                vol('line_b', vb, o.V_line)
            a_side, b_side = va, vb
        if parts['hose']:
            hose_b = parts['hose_b'] or parts['hose']
            out.append((f'{n}.hose', 'hose', parts['hose'], {'a': f'{n}.ha', 'b': a_side}))
            a_side = f'{n}.ha'
            if b_side is not None:
                out.append((f'{n}.hose_b', 'hose', hose_b, {'a': f'{n}.hb', 'b': b_side}))
                b_side = f'{n}.hb'
        elif parts['hose_b']:
            raise ParamError([f"{n}: hose_b.* given without hose.* (the A line's)"])
        valve_ports = {'T': tank, **({'ls': sense} if sense else {})}
        if o.compensator == 'post':
            if not self.ports.get('ls'):
                raise ParamError([f'{n}: a post-compensated section needs its port ls (the '
                                  'load-sensing line)'])
            ls = self.ports['ls'][0]
            valve_ports['P'] = supply
            for side, line, mid in (('a', a_side, f'{n}.mid'), ('b', b_side, f'{n}.mid_b')):
                if line is None:
                    continue
                valve_ports['A' if side == 'a' else 'B'] = mid
                valve_ports['sense_A' if side == 'a' else 'sense_B'] = line
                suffix = '' if side == 'a' else '_b'
                out += [(f'{n}.comp{suffix}', 'post_compensator', parts['comp'],
                         {'in': mid, 'out': line, 'ls': ls}),
                        (f'{n}.return{suffix}', 'check_valve', {'A': 1.0e-4, 'p_crack': 1.0e4,
                                                                'p_full': 1.0e5},
                         {'in': line, 'out': mid})]
                vol(f'mid_volume{suffix}', mid, o.V_mid)
        else:
            valve_ports.update(A=a_side, **({'B': b_side} if b_side else {}))
            if o.compensator == 'pre':
                valve_ports['P'] = f'{n}.mid'
                out.append((f'{n}.comp', 'pre_compensator', {'check': True, **parts['comp']},
                            {'in': supply, 'out': f'{n}.mid', 'sense': sense or load}))
                vol('mid_volume', f'{n}.mid', o.V_mid)
            else:
                valve_ports['P'] = supply
        out.append((f'{n}.valve', 'valve_4_3', parts['valve'], valve_ports))
        if sense:
            vol('sense_volume', sense, o.V_sense)
        if parts['relief']:
            if act == 'motor':  # cross-port: each line to the other
                out += [(f'{n}.relief_ab', 'relief', parts['relief'], {'in': load, 'out': load_b}),
                        (f'{n}.relief_ba', 'relief', parts['relief'], {'in': load_b, 'out': load})]
            else:
                out += [(f'{n}.relief_{s}', 'relief', parts['relief'], {'in': node, 'out': tank})
                        for s, node in (('a', load), ('b', load_b)) if node]
        if o.makeup or parts['check']:
            check = {'A': 1.0e-4, 'p_crack': 3.0e4, 'p_full': 2.0e5, **parts['check']}
            out += [(f'{n}.makeup_{s}', 'check_valve', check, {'in': tank, 'out': node})
                    for s, node in (('a', load), ('b', load_b)) if node]
        out.append((f'{n}.{act}', act, parts[act],
                    {'a': load, **({'b': load_b} if load_b else {})}))
        inputs = {'command': f'{n}.valve.command'}
        signals = {'flow': f'{n}.comp.flow' if o.compensator == 'post' else f'{n}.valve.flow_A',
                   'pressure': f'{n}.{act}.pressure', 'pressure_b': f'{n}.{act}.pressure_b',
                   'opening': f'{n}.valve.spool'}
        if act == 'cylinder':
            inputs['force'] = f'{n}.cylinder.force'
            signals.update(position=f'{n}.cylinder.position', velocity=f'{n}.cylinder.velocity')
        else:
            inputs['torque'] = f'{n}.motor.torque'
            signals.update(speed=f'{n}.motor.speed', angle=f'{n}.motor.angle')
        # Parts that take a group's values under another name (a side's compensator, the
        # brake valves, the reliefs): where their --set values live.
        groups = {name: g for name, _, values, _ in out for g, d in parts.items()
                  if d and values is d and name != f'{n}.{g}'}
        return Expansion(out, inputs, signals, groups)
