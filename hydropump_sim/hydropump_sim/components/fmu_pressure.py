"""A user's FMU that sets a node's pressure (``type: fmu_pressure``): the FMU (stepped
beside the circuit, hydropump_ctrl/fmi/loads.py) takes the net flow into it from the node
and returns the node's pressure (a volume, an accumulator, a line of its own); here that
pressure, held over each step as the input ``pressure``, is the node's, as a pressure
source holds it. Its signal ``flow`` is the net flow into it (the compiler's, as a tank's).

The component holds no FMU itself (the plant library steps no FMU).
"""

from dataclasses import dataclass

from ..jitcache import jit
from ..schema import spec
from .base import InputSpec, PortSpec, SignalSpec
from .fmu_load import fmu_parameters_spec, FmuComponent


@jit
def kernel(t, x, dx, u, p, y, P, Q, V):
    y[0] = P[int(p[0])]      # the net flow into it (y[1]) is the compiler's, as a tank's


@dataclass(frozen=True)
class FmuPressureParams:
    file: str = spec('-', 'the FMU file (FMI 2.0 or 3.0), relative to the circuit '
                     "file's folder")
    flow_input: str = spec('-', "the FMU's real input that takes the net flow into it from "
                           'the node [m^3/s]', default='flow')
    pressure_output: str = spec('-', "the FMU's real output: the node's pressure [Pa gauge]",
                                default='pressure')
    parameters: list = fmu_parameters_spec()


class FmuPressureLoad(FmuComponent):
    kind = 'fmu_pressure'
    doc = "a user's FMU that sets a node's pressure: the flow into it in, the pressure out"
    Params = FmuPressureParams
    PORTS = (PortSpec('node', 'the node whose pressure it sets'),)
    INPUTS = (InputSpec('pressure', 'Pa', "the FMU's pressure, held over a step", -1.0e5,
                        1.0e8, 0.0),)
    SIGNALS = (SignalSpec('pressure', 'Pa', "the node's pressure, the FMU's"),
               SignalSpec('flow', 'm^3/s', 'net flow into the FMU, its input'))
    kernel = kernel
    EXTERNAL_RETURN = True
    ROLES = frozenset({'load', 'external'})
    LOAD_SIGNALS = {'pressure': 'pressure', 'flow': 'flow'}

    def pressure_cap(self, u):
        return u['pressure']

    def fixed_pressure(self):
        return ('node', 'input', 'pressure')

    def exchange(self) -> tuple[str, str, str, str]:
        prm = self.params
        return prm.flow_input, 'flow', prm.pressure_output, 'pressure'
