"""Circuit speed: the circuit of Fig. 1 through the report's 4 s operator cycle (and 0.5 s
before it), beside today's plant (the paper's pump and orifice, the same current and
aperture steps as bench_plant) measured in the same run.

Rows, each a real-time factor and its cost against the plant's same row:
- offline, ``simulate`` of the circuit / of the plant (adaptive Rodas4 steps; the circuit under
  the hydromechanical load-sensing pump, so no controller), and the same without the
  steady-state search each call starts with;
- as the simulator node steps it, ``Simulator.step`` of each once a
  millisecond;
- closed loop under EMC margin control (``run_circuit``: the circuit, the bench's sensors
  and the controller's law each millisecond, as the two nodes run it), pre- and
  post-compensated.

Goal: Fig. 1 >= 100x real time.
"""

from pathlib import Path
import statistics
import sys
import time

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from hydropump_ctrl.experiments.circuit_loop import controller_config, hydromechanical, run_circuit  # noqa: E402
from hydropump_ctrl.experiments.fig1 import DURATION, held_inputs, MARGIN, START  # noqa: E402
from hydropump_sim import load_params, simulate, Simulator  # noqa: E402
from hydropump_sim.circuit import load_circuit  # noqa: E402
from hydropump_sim.params import default_params_path  # noqa: E402
from hydropump_sim.scaling import current_for_displacement  # noqa: E402
from hydropump_sim.steady import equilibrium  # noqa: E402

from common import emit, median_time, row  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SETTLE = 0.5  # s run before the cycle (the preroll of the report's runs)


def duty_inputs():
    """The report's duty cycle as functions of time, one per input."""
    def held(name):
        return lambda t: held_inputs(np.atleast_1d(np.asarray(t, dtype=float)))[name]
    return {name: held(name) for name in START}


def timed(fn, repeat: int = 5) -> float:
    fn()  # compile or load the cache outside the timing
    return median_time(fn, repeat=repeat)[0]


def plant_seconds(duration: float) -> tuple[float, float]:
    """Wall times of ``duration`` s of the paper's plant (a current step, an aperture
    step): offline by ``simulate``, and one ``step()`` per millisecond as the node."""
    p = load_params(default_params_path())
    I0, I1 = current_for_displacement(p, [0.4, 0.6])
    sim = Simulator(p, dt=1e-3)
    n = int(round(duration / 1e-3))

    def stepped():
        sim.reset(I0)
        for k in range(n):
            sim.set_inputs(current=I1 if k > n // 4 else I0, aperture=0.6 if k > n // 2
                           else 0.5)
            sim.step()

    def offline():
        simulate(p, duration, current=lambda t: np.where(np.asarray(t) < duration / 4,
                                                              I0, I1),
                 aperture=lambda t: np.where(np.asarray(t) < duration / 2, 0.5, 0.6))
    return timed(offline), timed(stepped)


def fig1_stepped(circuit, duration: float) -> float:
    """Wall time of ``duration`` s of ``circuit`` through the duty cycle, one
    ``Simulator.step()`` per millisecond (median of 3; each run's steady-state
    search at its start, the node's ~/reset, outside the timing)."""
    sim = Simulator(circuit, 1e-3)
    t = np.arange(int(round(duration / 1e-3))) * 1e-3 - SETTLE
    table = held_inputs(np.maximum(t, 0.0))
    index = [circuit.input_index(n) for n in table]
    columns = np.array(list(table.values())).T
    times = []
    for _ in range(4):  # the first compiles or loads the cache
        sim.u[index] = columns[0]
        sim.reset()
        t0 = time.perf_counter()
        for row_k in columns:
            sim.u[index] = row_k
            sim.step()
        times.append(time.perf_counter() - t0)
    return statistics.median(times[1:])


def main():
    fig1 = load_circuit(ROOT / 'config' / 'circuits' / 'fig1.yaml')
    inputs = duty_inputs()
    simulated = DURATION + SETTLE
    t_off, t_step = plant_seconds(simulated)
    rows = [row('real-time factor, the paper plant, simulate()', simulated / t_off, 'x', '',
                None, 'baseline, same run'),
            row('real-time factor, the paper plant, Simulator.step() at 1 kHz',
                simulated / t_step, 'x', '', None, 'baseline, same run')]
    ls = hydromechanical(fig1, MARGIN)
    eq = equilibrium(ls, ls.input_vector(START))
    t_sim = timed(lambda: simulate(ls, simulated, inputs), repeat=3)
    t_sim_x0 = timed(lambda: simulate(ls, simulated, inputs, x0=eq.x), repeat=3)
    t_fig1_step = fig1_stepped(ls, simulated)
    for label, t, base in (('simulate()', t_sim, t_off),
                           ('simulate() from a given state', t_sim_x0, t_off),
                           ('Simulator.step() at 1 kHz', t_fig1_step, t_step)):
        rows.append(row(f'real-time factor, Fig. 1 duty cycle, LS pump, {label}',
                        simulated / t, 'x', '>= 100', simulated / t >= 100,
                        f"{t / base:.1f}x the plant's time"))
    for label, control, kind in (('EMC margin control, pre', 'margin', 'pre'),
                                 ('EMC margin control, post', 'margin', 'post')):
        c = fig1.with_values({'boom.compensator': kind, 'motor.compensator': kind})

        # The controller's design (the node's start-up) stays outside the timing.
        cfg = controller_config(c) if control == 'margin' else None

        def run(c=c, control=control, cfg=cfg):
            return run_circuit(c, DURATION, inputs, control=control, config=cfg,
                               algorithm='emc' if control == 'margin' else None,
                               settle=SETTLE)
        t = timed(run, repeat=3)
        rows.append(row(f'real-time factor, Fig. 1 duty cycle, {label}, run_circuit()',
                        simulated / t, 'x', '', None, f"{t / t_step:.1f}x the plant's "
                        'time stepped'))
    emit(rows)


if __name__ == '__main__':
    main()
