"""A load section of a load-sensing valve block (a composite): a proportional meter-in
valve, a pressure compensator before it (``pre``), after it (``post``, flow sharing) or
none (a priority load, whose priority valve compensates it), and the actuator it drives (a
cylinder or a motor). Its ports: ``supply``, ``tank``, ``load`` (the actuator's node, which
the shuttle network senses) and ``ls`` (the load-sensing line, for ``post``).

Parameters: ``actuator``, ``compensator``, ``V_mid`` (the volume between compensator and
valve), and the parts' own under ``valve.``, ``comp.`` and ``cylinder.`` or ``motor.``.
The section's inputs are ``command`` (the valve, 0..1) and ``force`` or ``torque``; its
signals ``flow`` (metered), ``pressure`` (the load's), ``opening``, and ``position`` and
``velocity`` or ``speed``. Every part's own inputs and signals stay reachable by their full
names (``boom.comp.opening``).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from ..schema import build, ParamError, spec, unknown_key_line
from .base import Component, Expansion, InputSpec, PortSpec, SignalSpec

GROUPS = ('valve', 'comp', 'cylinder', 'motor')


@dataclass(frozen=True)
class SectionOptions:
    actuator: str = spec('-', 'what the section drives', choices=('cylinder', 'motor'))
    compensator: str = spec('-', 'pressure compensator: pre (before the valve), post (after '
                            'it, flow sharing) or none', choices=('pre', 'post', 'none'),
                            default='pre')
    V_mid: float = spec('m^3', 'volume between the compensator and the valve', 1.0e-9, 1.0e-2,
                        default=1.0e-5)
    V_sense: float = spec('m^3', 'volume of the load-sensing signal passage', 1.0e-9, 1.0e-3,
                          default=1.0e-6)


@dataclass(frozen=True)
class SectionSetup:
    options: SectionOptions
    parts: dict[str, dict[str, Any]]


class Section(Component):
    kind = 'section'
    doc = 'load section: meter-in valve, pre/post/no compensator, cylinder or motor'
    PORTS = (PortSpec('supply', 'pressure supply'), PortSpec('tank', 'return'),
             PortSpec('load', "the actuator's node"),
             PortSpec('sense', "the section's load-sensing signal: the load pressure while "
                      'the valve is open, tank while it is closed', optional=True),
             PortSpec('ls', 'load-sensing line (post-compensated sections)', optional=True))
    INPUTS = (InputSpec('command', '-', 'valve command 0..1', 0.0, 1.0, 0.0),
              InputSpec('force', 'N', 'cylinder: external force', -1.0e7, 1.0e7, 0.0),
              InputSpec('torque', 'N m', 'motor: load torque', -1.0e6, 1.0e6, 0.0))
    SIGNALS = (SignalSpec('flow', 'm^3/s', 'metered flow to the load'),
               SignalSpec('pressure', 'Pa', 'load pressure'),
               SignalSpec('opening', '-', 'valve spool opening'),
               SignalSpec('position', 'm', 'cylinder position'),
               SignalSpec('velocity', 'm/s', 'cylinder velocity'),
               SignalSpec('speed', 'rad/s', 'motor speed'))

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
        own_names = ('actuator', 'compensator', 'V_mid', 'V_sense')
        names = [f'{g}.' for g in GROUPS] + list(own_names)
        errors = [unknown_key_line(k, names) for k in own if k not in own_names]
        if errors:
            raise ParamError(errors, source)
        return SectionSetup(build(SectionOptions, own, source), parts)

    @classmethod
    def param_specs(cls):
        from ..schema import spec_map
        return spec_map(SectionOptions)

    def expand(self) -> Expansion:
        o, parts, n = self.params.options, self.params.parts, self.name
        supply, tank, load = (self.ports[k][0] for k in ('supply', 'tank', 'load'))
        act = o.actuator
        other = 'motor' if act == 'cylinder' else 'cylinder'
        if parts[other]:
            raise ParamError([f'{n}: {other}.* given, but the actuator is a {act}'])
        if o.compensator == 'none' and parts['comp']:
            raise ParamError([f'{n}: comp.* given, but the section has no compensator'])
        mid = f'{n}.mid'
        sense = self.ports.get('sense', [None])[0]
        gate = {'ls': sense, 'drain': tank} if sense else {}
        out: list = []
        if o.compensator == 'none':
            out.append((f'{n}.valve', 'directional_valve', parts['valve'],
                        {'in': supply, 'out': load, **gate}))
        elif o.compensator == 'pre':
            out += [(f'{n}.comp', 'pre_compensator', parts['comp'],
                     {'in': supply, 'out': mid, 'sense': load}),
                    (f'{n}.valve', 'directional_valve', parts['valve'],
                     {'in': mid, 'out': load, **gate})]
        else:
            if not self.ports.get('ls'):
                raise ParamError([f'{n}: a post-compensated section needs its port ls (the '
                                  'load-sensing line)'])
            # The metering edge discharges into mid; the signal is the load's, behind the
            # compensator, switched by the same spool.
            out += [(f'{n}.valve', 'directional_valve', parts['valve'],
                     {'in': supply, 'out': mid, **gate, **({'ls_from': load} if sense else {})}),
                    (f'{n}.comp', 'post_compensator', parts['comp'],
                     {'in': mid, 'out': load, 'ls': self.ports['ls'][0]})]
        if o.compensator != 'none':
            out.append((f'{n}.mid_volume', 'volume', {'V': o.V_mid}, {'node': mid}))
        if sense:
            out.append((f'{n}.sense_volume', 'volume', {'V': o.V_sense}, {'node': sense}))
        out.append((f'{n}.{act}', act, parts[act], {'a': load, 'b': tank}))
        inputs = {'command': f'{n}.valve.command'}
        signals = {'flow': f'{n}.valve.flow', 'pressure': f'{n}.{act}.pressure',
                   'opening': f'{n}.valve.opening'}
        if act == 'cylinder':
            inputs['force'] = f'{n}.cylinder.force'
            signals.update(position=f'{n}.cylinder.position', velocity=f'{n}.cylinder.velocity')
        else:
            inputs['torque'] = f'{n}.motor.torque'
            signals['speed'] = f'{n}.motor.speed'
        return Expansion(out, inputs, signals)
