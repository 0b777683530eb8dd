"""A user's FMU as a load at a node (``type: fmu``): the FMU (stepped beside the circuit,
hydropump_ctrl/fmi/loads.py) takes the node's pressure and returns the flow it draws; here
that flow, held over each step as the input ``flow``, leaves the node. (``fmu_pressure``,
the FMU that sets a node's pressure, is in fmu_pressure.py.)

The coupling is explicit co-simulation at the simulator's step: the flow of a step is the
FMU's answer to the pressure at the step's start. The component holds no FMU itself (the
plant library steps no FMU): a circuit with one runs behind the simulator node, or through
:mod:`hydropump_ctrl.fmi.loads`.
"""

from dataclasses import dataclass
import math

from ..jitcache import jit
from ..schema import ParamError, spec, text_number_hint
from .base import Component, InputSpec, PortSpec, SignalSpec

#: The circuit file's key of an FMU component's own parameters (``parameters: {Cd_A:
#: 3.0e-6}``, or ``--set boom_load.parameters.Cd_A=3e-6``).
PARAMETERS = 'parameters'


def fmu_parameters_spec():
    return spec('-', "the FMU's own real parameters set before each initialisation, "
                'NAME=VALUE (in a circuit file a mapping: parameters: {NAME: VALUE})',
                default=[])


class FmuComponent(Component):
    """What the two FMU components share: their FMU's own parameters, given by name."""

    @classmethod
    def build_params(cls, values, source=None):
        """The parameters, the mapping ``parameters`` (dotted: ``parameters.NAME``) kept as
        the list ``NAME=VALUE``; each value a finite number (one line each otherwise)."""
        given = {k[len(PARAMETERS) + 1:]: v for k, v in values.items()
                 if k.startswith(PARAMETERS + '.')}
        own = {k: v for k, v in values.items() if not k.startswith(PARAMETERS + '.')}
        items = own.get(PARAMETERS) or []
        if not isinstance(items, list):
            raise ParamError([f"{PARAMETERS}: expected a mapping of the FMU's parameter "
                              'names to numbers'], source)
        number = (lambda v: isinstance(v, (int, float)) and not isinstance(v, bool)  # noqa: E731
                  and math.isfinite(v))
        pairs = [p for p, item in zip(_pairs(items), items) if '=' in str(item)] + \
            [(n, float(v) if number(v) else v) for n, v in given.items()]
        errors = [f'{PARAMETERS}: {item!r}: expected NAME=VALUE' for item in items
                  if '=' not in str(item)]
        errors += [f'{PARAMETERS}.{n} = {v!r}: not a finite number{text_number_hint(v)}'
                   for n, v in pairs if not number(v)]
        errors += [f'{PARAMETERS}.{n}: a name with "=" or none is no FMU parameter'
                   for n, _ in pairs if '=' in n or not n.strip()]
        if errors:
            raise ParamError(errors, source)
        own[PARAMETERS] = [f'{n}={v!r}' for n, v in pairs]
        return super().build_params(own, source)

    def fmu_parameters(self) -> dict[str, float]:
        """The FMU's own parameters the circuit gives, by name."""
        return dict(_pairs(self.params.parameters))


def _pairs(items) -> list[tuple[str, object]]:
    """``NAME=VALUE`` items as (name, float), a value that is no finite number as given."""
    out = []
    for item in items:
        name, _, text = str(item).partition('=')
        value: object = text.strip()
        try:
            x = float(text)
            if math.isfinite(x):
                value = x
        except ValueError:
            pass
        out.append((name.strip(), value))
    return out


@jit
def kernel(t, x, dx, u, p, y, P, Q, V):
    a = int(p[0])
    Q[a] -= u[0]
    y[0] = u[0]
    y[1] = P[a]
    y[2] = P[a] * u[0]


@dataclass(frozen=True)
class FmuLoadParams:
    file: str = spec('-', 'the FMU file (FMI 2.0 or 3.0), relative to the circuit '
                     "file's folder")
    pressure_input: str = spec('-', "the FMU's real input that takes the node's pressure "
                               '[Pa gauge]', default='pressure')
    flow_output: str = spec('-', "the FMU's real output: the flow it draws from the node "
                            '[m^3/s]', default='flow')
    parameters: list = fmu_parameters_spec()


class FmuLoad(FmuComponent):
    kind = 'fmu'
    doc = "a user's FMU as a load: the node's pressure in, the flow it draws out"
    Params = FmuLoadParams
    PORTS = (PortSpec('in', 'the node it draws from'),)
    INPUTS = (InputSpec('flow', 'm^3/s', "the FMU's flow, held over a step", -1.0, 1.0,
                        0.0),)
    SIGNALS = (SignalSpec('flow', 'm^3/s', 'flow into the FMU'),
               SignalSpec('pressure', 'Pa', "the node's pressure, the FMU's input"),
               SignalSpec('work', 'W', 'power delivered to the FMU, P Q'))
    kernel = kernel
    EXTERNAL_RETURN = True
    ROLES = frozenset({'load', 'external'})
    LOAD_SIGNALS = {'pressure': 'pressure', 'flow': 'flow'}

    def exchange(self) -> tuple[str, str, str, str]:
        """What it trades with its FMU each step: the FMU's input and the signal that gives
        it, the FMU's output and the input it sets."""
        prm = self.params
        return prm.pressure_input, 'pressure', prm.flow_output, 'flow'
