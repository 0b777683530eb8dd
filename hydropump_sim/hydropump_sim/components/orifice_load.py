"""The paper's load (eq. 9): an orifice of aperture ``xi_u`` from its port to a held load
pressure ``P_u``,

    Q_load = mu_u xi_u (P - P_u)^(1/gamma_u)

turbulent for ``gamma_u = 2``, laminar for 1, with the laminar regularisation below
``dp_cr`` (docs/reference.md I3). The load pressure and the aperture are inputs.
"""

from dataclasses import dataclass

from ..jitcache import jit
from ..schema import spec
from .base import Component, InputSpec, PortSpec, SignalSpec
from .laws import groot


@jit
def load_flow(P, P_u, xi, mu, dp_cr, gamma):
    """Eq. 9's load flow [m^3/s] at port pressure ``P``."""
    return mu * xi * groot(P - P_u, dp_cr, gamma)


@jit
def kernel(t, x, dx, u, p, y, P, Q, V):
    a = int(p[0])
    q = load_flow(P[a], u[0], u[1], p[1], p[2], p[3])
    Q[a] -= q
    y[0] = q
    y[1] = u[0]
    y[2] = P[a] - u[0]
    y[3] = (P[a] - u[0]) * q
    y[4] = u[0] * q


@dataclass(frozen=True)
class OrificeLoadParams:
    mu: float = spec('m^3/(s Pa^(1/gamma))', 'load orifice coefficient (eq. 9)', 1.0e-12, 1.0e-2)
    load_pressure: float = spec('Pa', 'load pressure P_u downstream of the orifice', 1.0e4,
                                4.5e7)
    aperture: float = spec('-', 'aperture degree xi_u', 0.0, 1.0)
    gamma: float = spec('-', 'load law exponent: 2 turbulent, 1 laminar (eq. 9)', 1.0, 2.0,
                        default=2.0)
    dp_cr: float = spec('Pa', 'laminar/turbulent transition; 0 = root', 0.0, 1.0e6,
                        default=0.0)


class OrificeLoad(Component):
    kind = 'orifice_load'
    LOSS_GROUP = 'metering'
    doc = 'eq. 9: an orifice of aperture xi_u to a held load pressure P_u'
    Params = OrificeLoadParams
    PORTS = (PortSpec('in', 'the loaded node'),)
    INPUTS = (InputSpec('load_pressure', 'Pa', 'load pressure P_u', 1.0e4, 4.5e7,
                        'load_pressure'),
              InputSpec('aperture', '-', 'aperture degree xi_u', 0.0, 1.0, 'aperture'))
    SIGNALS = (SignalSpec('flow', 'm^3/s', 'load flow Q_load'),
               SignalSpec('load_pressure', 'Pa', 'load pressure P_u'),
               SignalSpec('dp', 'Pa', 'pressure drop across the orifice'),
               SignalSpec('loss', 'W', 'power dissipated in the orifice'),
               SignalSpec('work', 'W', 'power delivered to the load, P_u Q_load'))
    kernel = kernel
    EXTERNAL_RETURN = True
    ROLES = frozenset({'load'})
    MEASURES = {'load_flow': 'flow', 'load_pressure': 'load_pressure'}
    LOAD_SIGNALS = {'pressure': 'load_pressure', 'flow': 'flow'}
    PLANT_INPUTS = True

    def pressure_cap(self, u):
        return u['load_pressure']  # the held pressure pushes back when the line is below it

    def pack(self):
        r = self.params
        return [r.mu, r.dp_cr, r.gamma]
