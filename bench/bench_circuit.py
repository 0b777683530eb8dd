"""Circuit speed and accuracy, against the paper's plant in the same run and against Hopsan.

For each circuit of the shape of Hopsan's "Load Sensing System" example, with its kind of
transients (commands switching, pistons reaching their stops):

- ``three_loads`` under the hydromechanical LS pump, square-wave commands on its three
  sections (a 4 s period, staggered), 10 s;
- Fig. 1 under the hydromechanical LS pump, through the report's 4 s operator cycle and
  0.5 s before it;
- the excavator through its 14 s dig-lift-swing-dump cycle, its pump held at full current
  (its cut-off and LS relief limit it);

the rows give the real-time factor of the fine model offline (``simulate``, from its steady
state found once outside the timing) and as the simulator node steps it (one
``Simulator.step()`` a millisecond), and its error against a Radau reference at rtol 1e-9
(the largest deviation of every load's flow and pressure and of the supply pressure, % of
each signal's range over the run; the reference is cached in ``bench/.cache``). The
simplified rows run the same circuit with section IV's fast components made static
(``hydropump_sim.reduction.with_fidelity``, section IV's bandwidth; their error is judged
averaged over its period, as a controller sees it). Fig. 1 also runs closed loop under EMC
margin control, as the two nodes run it.

Compilation: circuits of 25 to 200 load sections, each compiled in a fresh process and
cache (wall time and peak memory of the compile).

Hopsan: where ``HOPSANCLI`` names a HopsanCLI binary (``HOPSAN_LIBRARY``: its default
component library, ``HOPSAN_MODEL``: the "Load Sensing System" example; built in a scratch
folder, see docs/circuits.md), its 30 s run at its default 1 ms step is timed in this run;
otherwise that row says it was skipped.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path
import re
import statistics
import subprocess
import sys
import tempfile
import time

import numpy as np
import yaml

sys.path.insert(0, str(Path(__file__).resolve().parent))
from hydropump_ctrl.demo import excavator, fig1  # noqa: E402
from hydropump_ctrl.experiments.circuit_loop import controller_config, hydromechanical, run_circuit  # noqa: E402
from hydropump_sim import (  # noqa: E402
    fixed_step,  # noqa: E402
    load_params,
    simulate,
    Simulator,
)
from hydropump_sim.circuit import load_circuit  # noqa: E402
from hydropump_sim.files import replacing  # noqa: E402
from hydropump_sim.metrics import moving_average  # noqa: E402
from hydropump_sim.params import default_params_path  # noqa: E402
from hydropump_sim.reduction import same_start, with_fidelity  # noqa: E402
from hydropump_sim.scaling import current_for_displacement  # noqa: E402
from hydropump_sim.steady import equilibrium  # noqa: E402

from common import emit, median_time, row  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
CIRCUITS = ROOT / 'config' / 'circuits'
CACHE = Path(__file__).resolve().parent / '.cache'
SETTLE = 0.5        # s run before Fig. 1's cycle (the preroll of the report's runs)
REF_RTOL = 1.0e-9
SECTIONS = (25, 50, 100, 200)


def timed(fn, repeat: int = 3) -> float:
    fn()  # compile or load the cache outside the timing
    return median_time(fn, repeat=repeat)[0]


def held(table):
    """Functions of time, one per input, from a schedule of held inputs."""
    def one(name):
        return lambda t: table(np.atleast_1d(np.asarray(t, dtype=float)))[name]
    return {name: one(name) for name in table(np.zeros(1))}


def square(names, period: float):
    """Square waves between closed and fully open, staggered by a third of a period."""
    return {n: (lambda t, j=j: np.where(((np.asarray(t) + j * period / 3) // (period / 2))
                                        % 2 == 0, 0.0, 1.0)) for j, n in enumerate(names)}


def cases():
    """(name, model, inputs, duration) of each circuit."""
    tl = hydromechanical(load_circuit(CIRCUITS / 'three_loads.yaml'), 1.5e6)
    yield 'three_loads', tl, square([f'load{k}.command' for k in (1, 2, 3)], 4.0), 10.0
    f1 = hydromechanical(load_circuit(CIRCUITS / 'fig1.yaml'), fig1.MARGIN)
    ins = held(lambda t: fig1.held_inputs(np.maximum(t - SETTLE, 0.0)))
    yield 'Fig. 1', f1, ins, fig1.DURATION + SETTLE
    ex = load_circuit(CIRCUITS / 'excavator.yaml')
    ins = held(excavator.held_inputs)
    ins['pump.current'] = ex.plant_params().current_range[1]
    yield 'excavator', ex, ins, excavator.DURATION


def judged(model) -> list[str]:
    """Every load's flow and pressure, and the supply pressure."""
    out = [model.measured().get('line_pressure', 'pump.P_l')]
    for sig in model.loads().values():
        out += [sig[k] for k in ('flow', 'pressure') if k in sig]
    return out


def error(model, ref, res) -> tuple[float, str]:
    """The largest deviation of the judged signals, % of each one's range in the
    reference, and which."""
    worst = (0.0, '')
    for name in judged(model):
        a, b = ref[name], res[name]
        span = max(float(np.ptp(a)), 1e-9)
        worst = max(worst, (100.0 * float(np.max(np.abs(a - b))) / span, name))
    return worst


def reference(model, duration, inputs, x0) -> dict:
    """The Radau reference's judged signals (cached on the model's code, parameters,
    inputs and start)."""
    t = np.arange(int(round(duration / 1e-3))) * 1e-3
    U, _ = model.input_table(t, inputs, 1e-3)
    key = hashlib.sha256(b''.join([getattr(model, 'code', '').encode(), model.p.tobytes(),
                                   U.tobytes(), np.asarray(x0).tobytes(),
                                   repr(REF_RTOL).encode()])).hexdigest()[:20]
    path = CACHE / f'reference-{key}.npz'
    if path.exists():
        with np.load(path) as z:
            return {k: z[k] for k in z.files}
    t0 = time.perf_counter()
    res = simulate(model, duration, inputs, x0=x0, method='radau', rtol=REF_RTOL)
    print(f'  (Radau reference of {model.name}: {time.perf_counter() - t0:.0f} s, cached)',
          flush=True)
    out = {k: res[k] for k in judged(model)}
    CACHE.mkdir(exist_ok=True)
    with replacing(path, 'reference') as tmp:  # whole or not at all (an interrupted run)
        np.savez(tmp, **out)
    return out


def stepped(model, duration: float, inputs, x0) -> float:
    """Wall time of ``duration`` s stepped a millisecond at a time as the node steps
    (median of 3 after a first run; each run's reset outside the timing)."""
    sim = Simulator(model, 1e-3, x0=x0)
    t = np.arange(int(round(duration / 1e-3))) * 1e-3
    U, _ = model.input_table(t, inputs, 1e-3)
    times = []
    for _ in range(4):
        sim.u[:] = U[0]
        sim.x = np.array(x0, dtype=float)
        sim.t, sim.steps = 0.0, 0
        t0 = time.perf_counter()
        for u in U:
            sim.u[:] = u
            sim.step()
        times.append(time.perf_counter() - t0)
    return statistics.median(times[1:])


def plant_seconds(duration: float) -> tuple[float, float]:
    """Wall times of ``duration`` s of the paper's plant (a current step, an aperture
    step): offline by ``simulate``, and one ``step()`` per millisecond as the node."""
    p = load_params(default_params_path())
    I0, I1 = current_for_displacement(p, [0.4, 0.6])
    sim = Simulator(p, dt=1e-3)
    n = int(round(duration / 1e-3))

    def steps():
        sim.reset({'pump.current': I0})
        for k in range(n):
            sim.set_input('pump.current', I1 if k > n // 4 else I0)
            sim.set_input('load.aperture', 0.6 if k > n // 2 else 0.5)
            sim.step()

    def offline():
        simulate(p, duration, current=lambda t: np.where(np.asarray(t) < duration / 4,
                                                              I0, I1),
                 aperture=lambda t: np.where(np.asarray(t) < duration / 2, 0.5, 0.6))
    return timed(offline, 5), timed(steps, 5)


def circuit_rows(t_plant: float) -> list[dict]:
    rows = []
    for name, model, inputs, duration in cases():
        u0 = model.input_table(np.zeros(1), inputs, 1e-3)[0][0]
        x0 = equilibrium(model, u0).x
        ref = reference(model, duration, inputs, x0)
        res = simulate(model, duration, inputs, x0=x0)
        t_off = timed(lambda m=model, d=duration, i=inputs, x=x0: simulate(m, d, i, x0=x))
        t_step = stepped(model, duration, inputs, x0)
        e, which = error(model, ref, res)
        steps = res.stats['accepted'] + res.stats['rejected']
        rows += [row(f'{name}, fine: real-time factor, simulate()', duration / t_off, 'x',
                     '>= 150' if name != 'excavator' else '>= 50',
                     duration / t_off >= (150 if name != 'excavator' else 50),
                     f"{t_off / t_plant:.1f}x the plant's time; {steps / duration:.0f} "
                     'steps per simulated s'),
                 row(f'{name}, fine: real-time factor, Simulator.step() at 1 kHz',
                     duration / t_step, 'x', '>= 100' if name != 'excavator' else '',
                     duration / t_step >= 100 if name != 'excavator' else None, ''),
                 row(f'{name}, fine: error against Radau rtol 1e-9', e, '% range', '<= 0.1',
                     e <= 0.1, which)]
        if name == 'excavator':
            continue
        sm, fid = with_fidelity(model, 'simplified')
        xs = same_start(model, x0, sm)
        res = simulate(sm, duration, inputs, x0=xs)
        t_s = timed(lambda m=sm, d=duration, i=inputs, x=xs: simulate(m, d, i, x0=x))
        # In the control bandwidth: both averaged over T = 1/bandwidth.
        width = int(round(1.0 / fid.bandwidth / 1e-3))
        e, which = error(model, {k: moving_average(v, width, edges='shrink')
                                 for k, v in ref.items()},
                         {k: moving_average(res[k], width, edges='shrink') for k in ref})
        raw, _ = error(model, ref, res)
        rows += [row(f'{name}, simplified: real-time factor, simulate()', duration / t_s,
                     'x', '>= 1000', duration / t_s >= 1000,
                     f'{fid.bandwidth:.3g} Hz; {len(fid.components)} components static: '
                     f'{", ".join(fid.components)}'),
                 row(f'{name}, simplified: error against the fine reference, in the control '
                     'bandwidth', e, '% range', '<= 1', e <= 1.0,
                     f'{which}; unaveraged {raw:.3g} %; stated bound {100 * fid.bound:.3g} % '
                     "of the test run's excursion")]
    return rows


def fixed_step_rows() -> list[dict]:
    """Each circuit stepped as the simulator node steps it with ``solver.fixed_step``: the
    largest step of the form 1 ms/n that its check takes at the default bound (16 Rodas4
    steps an increment), its cost per increment against the 1 ms period (p50, p99, max of
    the whole run, a single pass: the cost of each step is the figure) and its error
    against the Radau reference."""
    rows = []
    for name, model, inputs, duration in cases():
        if name == 'excavator':
            continue
        u0 = model.input_table(np.zeros(1), inputs, 1e-3)[0][0]
        x0 = equilibrium(model, u0).x
        ref = reference(model, duration, inputs, x0)
        checked = fixed_step.largest_step(model, 1e-3)
        if checked is None:
            rows.append(row(f'{name}, fixed step: p99 cost / period', float('nan'), '%',
                            '<= 20', False, 'no step down to 1 ms/16 holds'))
            continue
        step = checked.step
        sim = Simulator(model, 1e-3, x0=x0, fixed_step=step)
        t = np.arange(int(round(duration / 1e-3))) * 1e-3
        U, _ = model.input_table(t, inputs, 1e-3)
        sim.x, sim.t, sim.steps = np.array(x0, dtype=float), 0.0, 0
        costs, out = [], []
        for u in U:
            sim.u[:] = u
            c0 = time.perf_counter()
            sim.step()
            costs.append(time.perf_counter() - c0)
            out.append(sim.outputs())
        out = np.array(out)
        e, which = error(model, {k: v[1:] for k, v in ref.items()},
                         {k: out[:, model.signal_index(k)] for k in ref})
        c = np.array(costs) / 1e-3 * 100.0
        rows += [row(f'{name}, fixed step: p99 cost / period', float(np.percentile(c, 99)),
                     '%', '<= 20', float(np.percentile(c, 99)) <= 20.0,
                     f'step {step * 1e6:.4g} us, at most 16 a ms ({checked.evaluations} '
                     f'evaluations); p50 {np.median(c):.3g} %, max {c.max():.3g} %, '
                     f'{int(np.sum(c > 100))} increments over the period'),
                 row(f'{name}, fixed step: error against Radau rtol 1e-9', e, '% range', '',
                     None, which)]
    return rows


def closed_loop_rows(t_step_plant: float) -> list[dict]:
    """Fig. 1 under EMC margin control, as the two nodes run it (each millisecond)."""
    circuit = load_circuit(CIRCUITS / 'fig1.yaml')
    inputs = held(fig1.held_inputs)
    rows = []
    for kind in ('pre', 'post'):
        c = circuit.with_values({'boom.compensator': kind, 'motor.compensator': kind})
        cfg = controller_config(c)  # the controller node's start-up, outside the timing
        t = timed(lambda c=c, cfg=cfg: run_circuit(c, fig1.DURATION, inputs, control='margin',
                                                   config=cfg, algorithm='emc',
                                                   settle=SETTLE))
        simulated = fig1.DURATION + SETTLE
        rows.append(row(f'Fig. 1 cycle, EMC margin control, {kind}: real-time factor',
                        simulated / t, 'x', '', None,
                        f"{t / t_step_plant:.1f}x the plant's time stepped"))
    return rows


_COMPILE = """
import resource, sys, time
t0 = time.perf_counter()
from hydropump_sim.circuit import load_circuit
t1 = time.perf_counter()
c = load_circuit(sys.argv[1])
c.evaluate_c
print(c.n_states, time.perf_counter() - t1, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)
"""


def sections_file(folder: Path, n: int) -> Path:
    """``three_loads`` with ``n`` load sections."""
    doc = yaml.safe_load((CIRCUITS / 'three_loads.yaml').read_text())
    comps = {k: v for k, v in doc['components'].items() if not k.startswith('load')}
    for k in range(n):
        sec = yaml.safe_load(yaml.safe_dump(doc['components']['load1']))
        sec['ports'] = {'supply': 'supply', 'tank': 'tank', 'load': f's{k}_a',
                        'sense': f's{k}_ls'}
        comps[f's{k}'] = sec
    comps['ls']['ports']['in'] = [f's{k}_ls' for k in range(n)]
    doc.update(components=comps, name=f'sections_{n}', plant=str(CIRCUITS.parent / 'pump.yaml'))
    path = folder / f'sections_{n}.yaml'
    path.write_text(yaml.safe_dump(doc))
    return path


def compile_rows() -> list[dict]:
    """Compile time and peak memory of circuits of 25 to 200 sections, each in a fresh
    process with an empty compiled-circuit cache."""
    out = {}
    with tempfile.TemporaryDirectory() as tmp:
        for n in SECTIONS:
            env = dict(os.environ, HYDROPUMP_CACHE=str(Path(tmp) / f'cache{n}'))
            proc = subprocess.run([sys.executable, '-c', _COMPILE,
                                   str(sections_file(Path(tmp), n))],
                                  capture_output=True, text=True, env=env, timeout=1800)
            if proc.returncode != 0:
                raise RuntimeError(proc.stderr[-2000:])
            states, seconds, kib = proc.stdout.split()
            out[n] = (int(states), float(seconds), int(kib) / 1024)
            print(f'  {n} sections ({states} states): compiled in {float(seconds):.1f} s, '
                  f'peak {int(kib) / 1024:.0f} MB', flush=True)
    big = out[SECTIONS[-1]]
    growth = big[1] / out[SECTIONS[0]][1]
    linear = SECTIONS[-1] / SECTIONS[0]
    return [row(f'compile, {SECTIONS[-1]} sections ({big[0]} states): wall time', big[1], 's',
                '< 60', big[1] < 60, ''),
            row(f'compile, {SECTIONS[-1]} sections: peak memory', big[2], 'MB', '< 1000',
                big[2] < 1000, 'the whole process'),
            row(f'compile, growth from {SECTIONS[0]} to {SECTIONS[-1]} sections', growth, 'x',
                f'<= {linear:g} (linear)', growth <= linear,
                ', '.join(f'{n}: {v[1]:.1f} s' for n, v in out.items()))]


def hopsan_row(t_plant: float) -> dict:
    """Hopsan's "Load Sensing System", 30 s at its 1 ms step, if a HopsanCLI is given: the
    simulation time it prints (median of 5), as ``simulate()`` is timed here."""
    cli = os.environ.get('HOPSANCLI')
    name = "Hopsan 'Load Sensing System', 1 ms step: real-time factor"
    lib, model = os.environ.get('HOPSAN_LIBRARY'), os.environ.get('HOPSAN_MODEL')
    if not (cli and lib and model):
        return row(name, float('nan'), 'x', '', None,
                   'skipped: HOPSANCLI, HOPSAN_LIBRARY and HOPSAN_MODEL not all set')
    cmd = [cli, '-e', lib, '-m', model, '-s', '0,0.001,30']
    times, walls = [], []
    with tempfile.TemporaryDirectory() as tmp:  # where it writes its log file
        for _ in range(5):
            t0 = time.perf_counter()
            out = subprocess.run(cmd, capture_output=True, text=True, check=True, timeout=600,
                                 cwd=tmp).stdout
            walls.append(time.perf_counter() - t0)
            times.append(float(re.search(r'SimulationTime:\s*([0-9.eE+-]+)', out).group(1)))
    t = statistics.median(times)
    return row(name, 30.0 / t, 'x', '', None,
               f"{t / 30.0 / t_plant:.3f}x the plant's time; the whole process "
               f'{30.0 / statistics.median(walls):.0f}x')


def main():
    simulated = 4.5
    t_off, t_step = plant_seconds(simulated)
    rows = [row('the paper plant: real-time factor, simulate()', simulated / t_off, 'x', '',
                None, 'baseline, same run'),
            row('the paper plant: real-time factor, Simulator.step() at 1 kHz',
                simulated / t_step, 'x', '', None, 'baseline, same run')]
    rows += circuit_rows(t_off / simulated)
    rows += fixed_step_rows()
    rows += closed_loop_rows(t_step / simulated)
    rows.append(hopsan_row(t_off / simulated))
    rows += compile_rows()
    emit(rows)


if __name__ == '__main__':
    main()
