"""A sharp-edged orifice between ports ``a`` and ``b``, turbulent with the laminar
regularisation of the pump's orifices (docs/reference.md I3):

    Q = C_d A xi sqrt(2/rho) sroot(P_a - P_b),   sroot(dp) = dp / (dp^2 + dp_cr^2)^(1/4)

``sroot`` is ``sqrt(dp)`` well above ``dp_cr`` and linear through zero, so flow reverses
smoothly. ``xi`` is the aperture, an input (0..1).
"""

from dataclasses import dataclass
import math

from ..jitcache import jit
from ..schema import spec
from .base import Component, InputSpec, PortSpec, SignalSpec
from .laws import signed_root


@jit
def kernel(t, x, dx, u, p, y, P, Q, V):
    a, b = int(p[0]), int(p[1])
    dp = P[a] - P[b]
    q = p[2] * u[0] * signed_root(dp, p[3])
    Q[a] -= q
    Q[b] += q
    y[0] = q
    y[1] = dp
    y[2] = q * dp


@dataclass(frozen=True)
class OrificeParams:
    A: float = spec('m^2', 'orifice area', 1.0e-10, 1.0e-1)
    C_d: float = spec('-', 'discharge coefficient', 0.1, 1.0, default=0.65)
    dp_cr: float = spec('Pa', 'laminar/turbulent transition; 0 = pure square root', 0.0, 1.0e6,
                        default=1.0e5)
    aperture: float = spec('-', 'aperture 0..1 (an input)', 0.0, 1.0, default=1.0)


def coefficient(C_d: float, A: float, rho: float) -> float:
    """``C_d A sqrt(2/rho)`` [m^3/(s Pa^0.5)]: flow per square root of pressure drop."""
    return C_d * A * math.sqrt(2.0 / rho)


class Orifice(Component):
    kind = 'orifice'
    LOSS_GROUP = 'lines'
    doc = 'turbulent orifice C_d A sqrt(2 dp/rho), laminar near zero drop'
    Params = OrificeParams
    PORTS = (PortSpec('a', 'inlet'), PortSpec('b', 'outlet'))
    INPUTS = (InputSpec('aperture', '-', 'aperture 0..1', 0.0, 1.0, 'aperture'),)
    SIGNALS = (SignalSpec('flow', 'm^3/s', 'flow a -> b'),
               SignalSpec('dp', 'Pa', 'pressure drop a - b'),
               SignalSpec('loss', 'W', 'power dissipated, dp q'))
    kernel = kernel

    def pack(self):
        r = self.params
        return [coefficient(r.C_d, r.A, self.fluid.rho), r.dp_cr]
