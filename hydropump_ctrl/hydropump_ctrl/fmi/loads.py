"""The FMU loads of a circuit (``type: fmu``, hydropump_sim/components/fmu_load.py), stepped
beside it: explicit co-simulation at the simulator's step.

Before each increment of the circuit every FMU load takes the pressure of its node
(its ``pressure_input``, Pa gauge), steps over the increment, and its ``flow_output`` is the
flow the circuit's component draws from the node over that increment (held). A reset starts
from a steady state of the two together: the held flow the FMU gives at the circuit's
steady pressure at that flow (:meth:`FmuLoads.start`).

The explicit coupling is stable while the FMU's flow changes little with the pressure over
one step of the node's pressure dynamics (``dt beta / V dQ/dp`` well below 1: a load at a
node with a volume, as every hydraulic port has); a stiffer one rings at the step's
frequency. Nothing here imports ROS.
"""

from __future__ import annotations

import math
from pathlib import Path

from hydropump_sim.components.fmu_load import FmuLoad
from hydropump_sim.simulate import Simulator

from .export import FmuError
from .instance import FmuInstance
from .reading import read_fmu

#: A reset's steady state of the circuit and its FMU loads together: passes over the loads
#: (and damped iterations of one where bisection has no bracket), the damping, and the
#: relative flow they agree to.
START_PASSES = 30
START_DAMPING = 0.5
START_TOLERANCE = 1.0e-10
#: How closely the FMU's answer at the start agrees with the flow held (relative): the
#: circuit's steady pressure at a held flow is only as sharp as its trim, and steep where a
#: pump's flow is flat in the pressure.
START_AGREEMENT = 1.0e-4


class FmuLoads:
    """Every FMU load of ``circuit``, unpacked, loaded and checked (:class:`FmuError` with a
    line per problem: the file, an FMU that is not one, a variable its mapping names that is
    missing or not Real)."""

    def __init__(self, circuit):
        self.parts = []
        base = Path(circuit.source).parent if getattr(circuit, 'source', None) else Path('.')
        problems = []
        for pt in circuit.parts:
            comp = pt.comp
            if not isinstance(comp, FmuLoad):
                continue
            prm = comp.params
            path = Path(prm.file)
            path = path if path.is_absolute() else base / path
            try:
                info = read_fmu(path, inputs=[prm.pressure_input], outputs=[prm.flow_output])
            except FmuError as exc:
                problems += [f'{comp.name}: {ln}' for ln in exc.lines]
                continue
            bad = [n for n in (prm.pressure_input, prm.flow_output)
                   if info.variables[n].type != 'Real']
            if bad:
                problems.append(f'{comp.name}: {path}: {", ".join(bad)} not Real (the '
                                'pressure in and the flow out are numbers)')
                continue
            self.parts.append((comp.name, info, prm))
        if problems:
            raise FmuError(problems)
        self.instances = []
        try:
            for name, info, prm in self.parts:
                inst = FmuInstance(info, name)
                self.instances.append((name, inst, inst.vr[prm.pressure_input],
                                       inst.vr[prm.flow_output]))
        except BaseException:
            self.close()
            raise

    def __bool__(self) -> bool:
        return bool(self.parts)

    def _pressures(self, sim: Simulator) -> list[float]:
        y = sim.outputs()
        return [float(y[sim.model.signal_index(f'{name}.pressure')])
                for name, *_ in self.instances]

    def _answer(self, sim: Simulator, j: int) -> float:
        """FMU ``j`` initialised at its node's pressure now: the flow it answers."""
        name, inst, p_ref, q_ref = self.instances[j]
        p = self._pressures(sim)[j]
        inst.initialise({}, [p_ref], [p], at=sim.t)
        return float(inst.get([q_ref], at=sim.t)[0])

    def start(self, sim: Simulator) -> str | None:
        """Every FMU initialised at its node's pressure and ``sim`` reset at their flows,
        found together: for each FMU in turn the flow ``q`` with ``q = f(P(q))`` (``P(q)``
        the circuit's steady pressure at that held flow, ``f`` the FMU's answer), by
        bisection where ``q - f(P(q))`` changes sign between 0 and ``f(P(0))``, else a
        damped iteration; passes until none moves. Why not, if the answers then differ from
        the flows held by more than :data:`START_AGREEMENT`."""
        from scipy.optimize import brentq
        if not self.instances:
            return None
        flows = [0.0] * len(self.instances)

        def held(j: int, q: float) -> float:
            flows[j] = q
            Simulator.reset(sim, {f'{n}.flow': v for (n, *_), v in zip(self.instances, flows)},
                            keep_time=True)
            return q - self._answer(sim, j)
        change = math.inf
        for _ in range(START_PASSES):
            before = list(flows)
            for j in range(len(self.instances)):
                h0 = held(j, 0.0)
                q1 = -h0
                if q1 != 0.0 and h0 * held(j, q1) <= 0.0:
                    held(j, brentq(lambda q, j=j: held(j, q), min(0.0, q1), max(0.0, q1),
                                   xtol=START_TOLERANCE * abs(q1), rtol=1e-12))
                else:
                    q = 0.0
                    for _ in range(START_PASSES):
                        q += START_DAMPING * -held(j, q)
                    held(j, q)
            change = max(abs(a - b) for a, b in zip(flows, before))
            scale = max(max(abs(q) for q in flows), 1e-12)
            # One FMU is found in one pass; several until none moves.
            if len(flows) == 1 or change <= 1e3 * START_TOLERANCE * scale:
                break
        # Each FMU initialised at the pressure it now sees: does its answer agree?
        residual = max(abs(held(j, flows[j])) for j in range(len(flows)))
        if residual <= START_AGREEMENT * max(max(abs(q) for q in flows), 1e-12):
            return None
        return (f'the FMU loads and the circuit did not settle together: the FMU answers '
                f'{residual:.3g} m^3/s off the flow held; the run starts from there')

    def exchange(self, sim: Simulator) -> None:
        """One increment of every FMU from its node's pressure now; its flow held by
        ``sim`` over the increment."""
        for (name, inst, p_ref, q_ref), p in zip(self.instances, self._pressures(sim)):
            inst.set([p_ref], [p], at=sim.t)
            inst.step(sim.dt, at=sim.t)
            sim.set_input(f'{name}.flow', float(inst.get([q_ref], at=sim.t)[0]))

    def close(self) -> None:
        for _, inst, *_ in getattr(self, 'instances', []):
            inst.close()


class CoupledSimulator(Simulator):
    """A circuit's :class:`~hydropump_sim.simulate.Simulator` with its FMU loads stepped
    beside it (see the module); :meth:`close` frees them."""

    steps_external = True

    def __init__(self, circuit, dt: float = 1.0e-3, **kwargs):
        self.loads = FmuLoads(circuit)
        try:
            super().__init__(circuit, dt, **kwargs)
        except BaseException:
            self.loads.close()
            raise

    def reset(self, inputs=None, keep_time: bool = False, keep_inputs: bool = True) -> None:
        super().reset(inputs, keep_time, keep_inputs)
        note = self.loads.start(self)
        if note:
            self.reset_note = note

    def step(self) -> None:
        self.loads.exchange(self)
        super().step()

    def close(self) -> None:
        self.loads.close()
