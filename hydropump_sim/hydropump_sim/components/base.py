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

  ``kernel(t, x, dx, u, p, y, P, Q)``

  of the time ``t`` [s], its own states ``x`` (writing their rates into ``dx``), its inputs
  ``u``, its packed parameters ``p`` (the node index of each port first, then
  :meth:`Component.pack`), writing its signals into ``y``. ``P`` holds the pressure of every
  node [Pa gauge]; the kernel *adds* the flow it delivers into each port's node to ``Q``
  [m^3/s] (negative for a flow it takes). It must not read or write anything else.

and may override the methods below: its states (which can depend on its parameters, e.g. a
lag that is off), the volume it adds to a port's node, a pressure it fixes, its start
state. The circuit compiler (``hydropump_sim/circuit.py``) lays out the states, the inputs
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
    it keeps its initial value there."""

    name: str
    unit: str
    scale: float
    integrating: bool = False


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


@dataclass
class Expansion:
    """What a composite component is made of.

    ``parts``: ``(name, kind, parameters, ports)`` of each primitive (names are full, e.g.
    ``boom.valve``; ports map to node names, internal ones named ``<composite>.<node>``);
    ``inputs`` and ``signals``: the composite's own names -> ``'<part>.<name>'``.
    """

    parts: list[tuple[str, str, Mapping[str, Any], Mapping[str, Any]]]
    inputs: dict[str, str] = field(default_factory=dict)
    signals: dict[str, str] = field(default_factory=dict)


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
