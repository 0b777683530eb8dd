"""The FMU loads of a circuit (``type: fmu`` and ``fmu_pressure``,
hydropump_sim/components/fmu_load.py), stepped beside it: explicit co-simulation at the
simulator's step.

Before each increment of the circuit every FMU takes what its component gives it (its
node's pressure [Pa gauge], or the net flow into it [m^3/s]), steps over the increment, and
its output (the flow it draws, or the node's pressure) is the component's input over that
increment (held). A reset starts from a steady state of the two together
(:meth:`FmuLoads.start`).

The explicit coupling is stable while what the FMU gives changes little with what it takes
over one step of the node's dynamics (a flow load: ``dt beta / V dQ/dp`` well below 1, at a
node with a volume, as every hydraulic port has; a pressure load: a capacity of its own,
``dt dP/dQ`` small against the circuit's resistance); a stiffer one rings at the step's
frequency. Nothing here imports ROS.
"""

from __future__ import annotations

from pathlib import Path

from hydropump_sim.schema import closest_name
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
            if 'external' not in comp.ROLES:
                continue
            fmu_in, signal, fmu_out, circuit_in = comp.exchange()
            path = Path(comp.params.file)
            path = path if path.is_absolute() else base / path
            try:
                info = read_fmu(path, inputs=[fmu_in], outputs=[fmu_out])
            except FmuError as exc:
                problems += [f'{comp.name}: {ln}' for ln in exc.lines]
                continue
            bad = [n for n in (fmu_in, fmu_out) if not info.variables[n].real]
            if bad:
                problems.append(f'{comp.name}: {path}: {", ".join(bad)} not real (what it '
                                'takes and gives are numbers)')
                continue
            given = comp.fmu_parameters()
            known = [n for n, v in info.variables.items()
                     if v.causality == 'parameter' and v.real]
            unknown = [n for n in given if n not in known]
            for n in unknown:
                close = closest_name(n, known)
                problems.append(f'{comp.name}.parameters.{n}: {path} has no real parameter '
                                f'of that name' + (f' (did you mean {close}?)' if close else ''))
            if unknown:
                continue
            self.parts.append((comp.name, info, comp.exchange(), given))
        if problems:
            raise FmuError(problems)
        self.instances = []
        try:
            for name, info, (fmu_in, signal, fmu_out, circuit_in), given in self.parts:
                inst = FmuInstance(info, name)
                self.instances.append((name, inst, inst.vr[fmu_in], inst.vr[fmu_out],
                                       f'{name}.{signal}', f'{name}.{circuit_in}', given))
        except BaseException:
            self.close()
            raise

    def __bool__(self) -> bool:
        return bool(self.parts)

    def _given(self, sim: Simulator) -> list[float]:
        """What each FMU takes from the circuit now (its node's pressure, or the flow into
        it)."""
        y = sim.outputs()
        return [float(y[sim.model.signal_index(signal)])
                for _, _, _, _, signal, _, _ in self.instances]

    def parameters(self) -> dict[str, dict[str, float]]:
        """Each FMU load's real parameters by name: its starts, those the circuit gives
        set."""
        out = {}
        for name, info, _, given in self.parts:
            out[name] = {n: v.start for n, v in info.variables.items()
                         if v.causality == 'parameter' and v.real and v.start is not None}
            out[name].update(given)
        return out

    def _answer(self, sim: Simulator, j: int) -> float:
        """FMU ``j`` initialised at what it takes now: what it answers."""
        _, inst, in_ref, out_ref, _, _, given = self.instances[j]
        inst.initialise(given, [in_ref], [self._given(sim)[j]], at=sim.t)
        return float(inst.get([out_ref], at=sim.t)[0])

    def start(self, sim: Simulator) -> str | None:
        """Every FMU initialised at what it takes and ``sim`` reset at what they give, found
        together: for each FMU in turn the held value ``x`` (a flow, or a pressure) with
        ``x = f(s(x))`` (``s(x)`` what the circuit gives the FMU at its steady state with
        ``x`` held, ``f`` the FMU's answer after its initialisation), by bisection where
        ``x - f(s(x))`` changes sign between 0 and ``f(s(0))``, else a damped iteration;
        passes until none moves. Why not, if the answers then differ from the values held by
        more than :data:`START_AGREEMENT` (relative)."""
        from scipy.optimize import brentq
        if not self.instances:
            return None
        held_values = [0.0] * len(self.instances)

        def held(j: int, x: float) -> float:
            held_values[j] = x
            Simulator.reset(sim, {inst[5]: v for inst, v in zip(self.instances, held_values)},
                            keep_time=True)
            return x - self._answer(sim, j)

        def off(a: list[float], b: list[float]) -> float:
            return max(abs(x - y) / max(abs(x), abs(y), 1e-12) for x, y in zip(a, b))
        for _ in range(START_PASSES):
            before = list(held_values)
            for j in range(len(self.instances)):
                h0 = held(j, 0.0)
                x1 = -h0
                if x1 != 0.0 and h0 * held(j, x1) <= 0.0:
                    held(j, brentq(lambda x, j=j: held(j, x), min(0.0, x1), max(0.0, x1),
                                   xtol=START_TOLERANCE * abs(x1), rtol=1e-12))
                else:
                    x = 0.0
                    for _ in range(START_PASSES):
                        x += START_DAMPING * -held(j, x)
                    held(j, x)
            # One FMU is found in one pass; several until none moves.
            if len(held_values) == 1 or off(held_values, before) <= 1e3 * START_TOLERANCE:
                break
        # Each FMU initialised at what it now takes: do its answers agree?
        answers = [held_values[j] - held(j, held_values[j]) for j in range(len(held_values))]
        worst = off(answers, held_values)
        if worst <= START_AGREEMENT:
            return None
        return (f'the FMU loads and the circuit did not settle together: an FMU answers '
                f'{100 * worst:.3g} % off the value held; the run starts from there')

    def exchange(self, sim: Simulator) -> None:
        """One increment of every FMU from what it takes from the circuit now; what it gives
        held by ``sim`` over the increment."""
        for (_, inst, in_ref, out_ref, _, circuit_in, _), v in zip(self.instances,
                                                                   self._given(sim)):
            inst.set([in_ref], [v], at=sim.t)
            inst.step(sim.dt, at=sim.t)
            sim.set_input(circuit_in, float(inst.get([out_ref], at=sim.t)[0]))

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
