"""``python -m hydropump_sim.warm``: compile the plant, the stepper and the shipped circuits
once, so that no later process pays it (``make`` runs it after the install; a node's first
start would otherwise wait a minute for numba).

Every structure a shipped configuration runs is compiled: each circuit of
``config/circuits``, and Fig. 1 with post-compensated sections and with the hydromechanical
compensator on its pump, under either kind, ``three_loads`` under that compensator, the
section IV simplified form of each (``fidelity: simplified``), and the bounded step of
``solver.fixed_step``. Two worker processes share the work.
"""

from __future__ import annotations

from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
import sys
import time


def _plant() -> str:
    from . import load_params, simulate
    from .params import default_params_path
    from .simulate import Simulator
    p = load_params(default_params_path())
    simulate(p, 0.01)
    for model in ('simplified', 'simplified_Kc'):
        simulate(p, 0.01, model=model)
    sim = Simulator(p)
    sim.step()
    Simulator(p, fixed_step=sim.dt).step()     # the bounded step, one for every model
    return 'plant'


def _circuit(path: str, sets: dict) -> str:
    from .circuit import load_circuit
    from .reduction import with_fidelity
    from .simulate import simulate, Simulator
    c = load_circuit(path, sets)
    sim = Simulator(c)
    sim.step()
    simulate(c, 0.01, x0=sim.x)
    c.jacobian(0.0, sim.x, sim.u)
    with_fidelity(c, 'simplified')      # its simplified form, run once there
    return f'{Path(path).name} {sets or ""}'.strip()


def jobs(config: Path) -> list[tuple]:
    out: list[tuple] = [(_plant,)]
    for path in sorted((config / 'circuits').glob('*.yaml')):
        out.append((_circuit, str(path), {}))
    fig1 = config / 'circuits' / 'fig1.yaml'
    if fig1.is_file():
        out.append((_circuit, str(fig1), {'boom.compensator': 'post',
                                          'motor.compensator': 'post'}))
        for kind in ('pre', 'post'):
            out.append((_circuit, str(fig1), {'boom.compensator': kind,
                                              'motor.compensator': kind,
                                              'pump.type': 'ls_pump', 'pump.ls.margin': 2.5e6}))
    three = config / 'circuits' / 'three_loads.yaml'
    if three.is_file():
        out.append((_circuit, str(three), {'pump.type': 'ls_pump', 'pump.ls.margin': 2.5e6}))
    return out


def _run(job):
    return job[0](*job[1:])


def main(argv=None) -> int:
    from .params import default_params_path
    config = default_params_path().parent
    t0 = time.perf_counter()
    todo = jobs(config)
    # The plant and the stepper first: every circuit's code calls the stepper's.
    print(f'compiling: {_run(todo[0])} ({time.perf_counter() - t0:.0f} s)', flush=True)
    with ProcessPoolExecutor(max_workers=2) as pool:
        for done in pool.map(_run, todo[1:]):
            print(f'compiling: {done} ({time.perf_counter() - t0:.0f} s)', flush=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
