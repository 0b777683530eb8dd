"""The circuit compiler: a YAML description of components connected at named hydraulic
nodes becomes one compiled ``evaluate`` (right-hand side and outputs) for the stepper of
:mod:`hydropump_sim.integrator`.

A circuit file::

    name: paper                       # optional
    plant: ../pump.yaml               # a plant params file; 'plant.<group>.<name>' reads it
    fluid: {beta: 1.6e+9}             # optional: the circuit's fluid over the plant's
    components:
      pump: {type: pump, ports: {out: line}}
      line: {type: volume, ports: {node: line}, V: plant.line.V_l}
      load: {type: orifice_load, ports: {in: line}, mu: plant.line.mu_u, ...}

Each component names its ``type`` (``hydropump_sim/components``), connects each port to a
node (a list for a port that takes several), and gives its parameters, nested or dotted,
in SI units. The compiler checks everything and reports one line per problem naming the
component and the port; then it lays out

- the **states**: every component's own, then one pressure per node that has a volume
  (continuity, eqs. 3 and 9); a node whose pressure a component fixes (a tank) has none;
- the **inputs** ``<component>.<input>`` and the **signals** ``<component>.<signal>``
  (``y``: every node's pressure, net inflow and volume first, then the components'
  signals);
- the **parameters** ``p``: the fluid, each node's volume or fixed pressure, then each
  component's block (its ports' node indices, then its own values);

and generates the source of ``evaluate``: index tables and a loop per component type
calling its compiled kernel on each component's slices, then continuity at each node (the
source does not grow with the number of components, nor does numba's compile time). The
Jacobian the stepper needs is the compiled ``evaluate`` differenced one colour at a time:
the compiler derives the sparsity (a component couples its own states and the pressures at
its ports) and a colouring of it (columns that share no row move together), 13
evaluations for Fig. 1's 37 states. The source depends on the structure only (which
components, which ports, how many states), never on parameter values, so a file compiles
once per structure and is cached on disk for every later process, in a folder of the user's
own (:mod:`hydropump_sim.codecache`). The generated source holds indices and the package's
module names only: no name or value of the circuit file reaches it, and component and node
names must be identifiers besides (they name ROS topics).
"""

from .model import Circuit, CircuitError, default_circuit_path, Part
from .reading import build_circuit, load_circuit

__all__ = ['build_circuit', 'Circuit', 'CircuitError', 'default_circuit_path', 'load_circuit',
           'Part']
