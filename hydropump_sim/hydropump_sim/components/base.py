"""What every circuit component declares, and the contract of its compiled kernel.

A component type is a subclass of :class:`Component` in a module of its own under
``hydropump_sim/components/`` (the registry finds it there; nothing else is edited to add
one). It declares, as class attributes,

- ``kind``: the name a circuit file uses (``type: orifice``) and ``doc``, one line;
- ``Params``: its parameter schema, a frozen dataclass of :func:`~hydropump_sim.schema.spec`
  fields (units, ranges, one-line errors, as every schema of the project);
- ``PORTS``, ``INPUTS``, ``SIGNALS``: its hydraulic ports, its inputs (set by ``--set``,
  scenario files or the simulator node) and its output signals;
- ``kernel``: its equations, a numba function

  ``kernel(t, x, dx, u, p, y, P, Q, V)``

  of the time ``t`` [s], its own states ``x`` (writing their rates into ``dx``), its inputs
  ``u``, its packed parameters ``p`` (the node index of each port first, then
  :meth:`Component.pack`), writing its signals into ``y``. ``P`` holds the pressure of every
  node [Pa gauge]; the kernel *adds* the flow it delivers into each port's node to ``Q``
  [m^3/s] (negative for a flow it takes), and may add to ``V`` a volume [m^3] at a port's
  node that depends on its states (a cylinder chamber's ``A x``; the constant volumes of
  :meth:`Component.volumes` are there already). It must not read or write anything else;
- what it is to the rest of the suite, so that nothing outside it branches on its kind:
  ``ROLES`` (see :data:`ROLES`), ``MEASURES`` (the suite's measured signals it gives),
  ``LOAD_SIGNALS`` (the topics of a load), ``JOINTS`` (its ``joint_states`` entries),
  ``PLANT_INPUTS`` (its inputs are the operating point the simulator holds, not an
  operator's), and :meth:`Component.pressure_cap` (the highest pressure it can make).

and may override the methods below: its states (which can depend on its parameters, e.g. a
lag that is off), the volume it adds to a port's node, a pressure it fixes, its start
state. The circuit compiler (``hydropump_sim/circuit/``) lays out the states, the inputs
and the signals of every component, and generates one compiled ``evaluate`` that calls each
kernel with its slices, then applies continuity (eqs. 3 and 9) to every node with a volume.

A *composite* (a load section: valve, compensator and actuator) overrides :meth:`expand`
and returns the primitive components it is made of, with its own names for their inputs and
signals.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

from ..schema import build, ParamSpec, spec_map


@dataclass(frozen=True)
class PortSpec:
    """A hydraulic port: ``many`` takes a list of nodes (a shuttle network's inputs);
    ``optional`` may be left unconnected; ``sense`` only reads its node's pressure (no flow
    through it)."""

    name: str
    desc: str
    many: bool = False
    optional: bool = False
    sense: bool = False


@dataclass(frozen=True)
class StateSpec:
    """A state of a component: ``scale`` is its typical magnitude (tolerances and
    difference steps); an ``integrating`` state (a position) is not part of a steady state:
    it keeps its initial value there, unless it rests on one of its ``stops`` (a piston
    pressed on its end stop is still)."""

    name: str
    unit: str
    scale: float
    integrating: bool = False
    stops: tuple[float, float] | None = None


@dataclass(frozen=True)
class InputSpec:
    """An input: ``default`` is a value, or the name of the parameter that gives it."""

    name: str
    unit: str
    desc: str
    lo: float
    hi: float
    default: float | str

    def param_spec(self, prefix: str) -> ParamSpec:
        return ParamSpec(f'{prefix}{self.name}', float, self.unit, self.desc, (self.lo, self.hi),
                         live=True)


@dataclass(frozen=True)
class SignalSpec:
    name: str
    unit: str
    desc: str


@dataclass(frozen=True)
class JointSpec:
    """A ``joint_states`` entry: its name after the component's (``''``: the component's
    own), and the signals of its position and velocity (``None``: not published, 0)."""

    suffix: str
    position: str | None
    velocity: str | None


#: The energy account (the circuit sums them into ``power:*`` signals, hydropump_sim.energy):
#: a component's signals of these names [W], from the power its ports take,
#: ``sum P_port Q_into_it = loss + work + stored - supply``.
ENERGY_TERMS = {
    'loss': 'dissipated: throttling, friction, leakage (never negative)',
    'work': 'delivered to the world outside the circuit: a load force or torque times its '
            'speed (negative when the load drives)',
    'stored': 'the rate of energy it stores: kinetic, a spring, gas, its own volumes',
    'supply': 'hydraulic power it gives the circuit (a pump)',
}

#: Where a component's ``loss`` counts in the energy account (``LOSS_GROUP``).
LOSS_GROUPS = {
    'metering': 'metering edges of directional valves and load orifices',
    'compensators': 'pressure compensators, priority and reducing valves',
    'relief': 'relief valves: main, load-sensing, port and cross-port',
    'holding': 'holding valves: counterbalance, pilot-operated and check valves',
    'lines': 'hoses, restrictors and accumulator inlets',
    'actuators': 'friction, cushions and leakage in cylinders and motors',
    'signal': 'the load-sensing signal network: shuttles, passages and bleeds',
}

#: The roles a component may declare, and what each means to the suite.
ROLES = {
    'pump': "the circuit's pump: its flow and pressures are the suite's pump signals",
    'electric': 'a pump driven by the solenoid current (the current command reaches it)',
    'load': 'a load the simulator publishes (LOAD_SIGNALS) beside the pump',
    'actuator': 'a cylinder or motor: moves a load, its force or torque an input',
    'ls_sensor': 'gives the load-sensing pressure, what a margin is held against',
    'compensator': 'holds a pressure difference dp_set across a metering edge',
    'pressure_limit': 'limits a pressure (relief, cut-off): its flow counts as relieved',
    'external': "a model outside the circuit, stepped beside it (a user's FMU): its inputs "
                "are that model's outputs, no operator's",
}


@dataclass
class Expansion:
    """What a composite component is made of.

    ``parts``: ``(name, kind, parameters, ports)`` of each primitive (names are full, e.g.
    ``boom.valve``; ports map to node names, internal ones named ``<composite>.<node>``);
    ``inputs`` and ``signals``: the composite's own names -> ``'<part>.<name>'``;
    ``groups``: a part -> the composite's parameter group it takes its values from, where
    that is not the part's own last name (``boom.comp_b`` from ``boom.comp.*``).
    """

    parts: list[tuple[str, str, Mapping[str, Any], Mapping[str, Any]]]
    inputs: dict[str, str] = field(default_factory=dict)
    signals: dict[str, str] = field(default_factory=dict)
    groups: dict[str, str] = field(default_factory=dict)


class Component:
    """Base of every component type (see the module)."""

    kind: ClassVar[str] = ''
    doc: ClassVar[str] = ''
    Params: ClassVar[type]
    PORTS: ClassVar[tuple[PortSpec, ...]] = ()
    INPUTS: ClassVar[tuple[InputSpec, ...]] = ()
    SIGNALS: ClassVar[tuple[SignalSpec, ...]] = ()
    kernel: ClassVar[Any] = None
    #: Its flow leaves the circuit (a load to a held pressure): a return path of its own.
    EXTERNAL_RETURN: ClassVar[bool] = False
    #: Its ports are joined by a passage the oil can return through (a valve); an actuator
    #: is not one: what it takes at ``a`` it gives at ``b``, which must drain elsewhere.
    PASSAGE: ClassVar[bool] = True
    #: Names from :data:`ROLES`.
    ROLES: ClassVar[frozenset[str]] = frozenset()
    #: The suite's measured signals it gives (``hydropump_sim.measure.SIGNALS`` names, and
    #: ``ls_pressure``) -> its own signal.
    MEASURES: ClassVar[Mapping[str, str]] = {}
    #: A load's topics (``pressure``, ``flow``, ``position``, ``velocity``, ``speed``) -> its
    #: own signal.
    LOAD_SIGNALS: ClassVar[Mapping[str, str]] = {}
    JOINTS: ClassVar[tuple[JointSpec, ...]] = ()
    #: Its inputs are the operating point the simulator holds (the pump's current and
    #: speed, the paper load's pressure), not an operator's or a duty cycle's.
    PLANT_INPUTS: ClassVar[bool] = False
    #: Where its ``loss`` signal counts (:data:`LOSS_GROUPS`); '' if it has none.
    LOSS_GROUP: ClassVar[str] = ''

    def __init__(self, name: str, params: Any, ports: Mapping[str, list[str]],
                 fluid: Any = None):
        self.name = name
        self.params = params
        self.ports = dict(ports)
        #: The circuit's fluid (``hydropump_sim.params.Fluid``): density for orifices.
        self.fluid = fluid

    # ---- parameters -----------------------------------------------------------------------

    @classmethod
    def build_params(cls, values: Mapping[str, Any], source: str | None = None) -> Any:
        """The validated parameters from the circuit file's entries (dotted names).

        Raises :class:`~hydropump_sim.schema.ParamError` naming each bad entry.
        """
        return build(cls.Params, values, source)

    @classmethod
    def param_specs(cls) -> dict[str, ParamSpec]:
        return spec_map(cls.Params)

    # ---- structure ------------------------------------------------------------------------

    def port_problems(self) -> list[str]:
        """One line per way its optional ports are left open that its parameters do not
        allow (a bleed with no tank to drain to); empty when they are fine."""
        return []

    def states(self) -> tuple[StateSpec, ...]:
        return ()

    def pack(self) -> list[float]:
        """The parameters the kernel reads, after the port indices."""
        return []

    def volumes(self) -> dict[str, float]:
        """Volume [m^3] this component adds to the node of each named port."""
        return {}

    def fixed_pressure(self) -> tuple[str, str, str] | None:
        """``(port, 'param' or 'input', name)`` if this component fixes the pressure of a
        port's node (a tank, a pressure source)."""
        return None

    def static_values(self) -> dict[str, Any] | None:
        """Parameter values that make this component's dynamics static (singular
        perturbation, section IV): a lag set to zero, the pump's simplified model; ``None``
        if it has none to remove."""
        return None

    def dither_frequency(self) -> float:
        """Frequency [Hz] of a time dependence within a held increment (0: none)."""
        return 0.0

    def steady_pack(self) -> list[float]:
        """:meth:`pack` for a steady state: without what only oscillates about one (a
        dither, which would keep a steady-state march from ever settling)."""
        return self.pack()

    def input_default(self, spec: InputSpec) -> float:
        if isinstance(spec.default, str):
            return float(getattr(self.params, spec.default))
        return float(spec.default)

    def pressure_cap(self, u: Mapping[str, float]) -> float | None:
        """The highest pressure [Pa gauge] this component can make at a node with inputs
        ``u`` (a relief's full-flow pressure, a cut-off's setting, a held source, a load's
        force over its area), or ``None``: no circuit pressure may exceed the highest of
        them (the invariants of :mod:`hydropump_sim.invariants`)."""
        return None

    def cap_checks(self, cap: float) -> list[str]:
        """One line per way this component cannot work in a circuit whose sources make at
        most ``cap`` [Pa] (an accumulator precharged above it never takes oil)."""
        return []

    def relief_law(self) -> tuple[float, float, float] | None:
        """A relief's ``(p_crack, p_full, q_full)`` [Pa, Pa, m^3/s] (role
        ``pressure_limit``), for a controller's model of where the pump's flow goes."""
        return None

    def metering_drop(self, margin: float) -> float | None:
        """A compensator's drop [Pa] across its section's metering edge under a load-sensing
        ``margin`` [Pa] (role ``compensator``)."""
        return None

    def pressure_guess(self, u: Mapping[str, float]) -> dict[str, float]:
        """Pressures [Pa] this component expects at its ports in a steady state (a load
        holding its force), for the start of the steady-state search."""
        return {}

    def initial_state(self, P: Mapping[str, float], u: Mapping[str, float]) -> np.ndarray:
        """A start state for the equilibrium search, from the pressures at the ports
        (``P`` by port name; a ``many`` port gives its first node's) and the inputs."""
        return np.array([s.scale * 0.0 for s in self.states()])

    def expand(self) -> Expansion | None:
        """The primitives of a composite component (``None`` for a primitive)."""
        return None
