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

from ..jitcache import jit
from ..schema import spec
from .base import Component, InputSpec, PortSpec, SignalSpec


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
    pressure_input: str = spec('-', "the FMU's Real input that takes the node's pressure "
                               '[Pa gauge]', default='pressure')
    flow_output: str = spec('-', "the FMU's Real output: the flow it draws from the node "
                            '[m^3/s]', default='flow')


class FmuLoad(Component):
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
