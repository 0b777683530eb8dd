"""Calibration speed and accuracy on a pump this code did not make, beside a naive fit.

The bags come from ``tests/independent.py`` (the plant's equations by scipy Radau at rtol
1e-9, its own sensors: a 12.4 ms flow-meter delay off the 1 kHz grid, noise, quantisation):
the pump differs from config/pump.yaml by 12-45 % in the four usual parameters; two current
staircases at two load pressures and load-pressure steps (17 s of data); a held-out run (a
current sine with a load step) judges the calibrated file. Two sensor sets:

- **flow and line pressure** (a flow meter and one transducer, the load pressure as input);
- **four bench sensors** (also the actuator pressure).

On the same bags, from the same start (config/pump.yaml), in the same process:

- **the project**: ``calibrate()``;
- **the naive baseline**: scipy ``least_squares`` around ``hydropump_sim.simulate()``, with
  its own 2-point differences, the free parameters as log factors, one flow delay from a
  grid search at the start, no tricks; serial, BLAS on one thread as for the project.

Goal: at least 2x faster in wall time, never less accurate (worst parameter error and
held-out error). Medians of three runs each, each started once the cores have been idle for
2 s (``bench_sweep.wait_idle``).

**A fleet** (``calibrate --fleet``): four pumps, each 12-45 % from config/pump.yaml in its
own way, each with the three bags above (its own noise), every pump one task of the
execution layer (:mod:`hydropump_ctrl.batch`), the ways interleaved, each started once the
cores have been idle for 2 s (``bench_sweep.wait_idle``), medians of five:

- on a warm local Dask cluster of 2 workers against 1 (goal: >= 1.7x);
- without a cluster (in a process with no Dask in it): one pump after the other, each with
  its simulations on threads, and two pumps at once on threads;
- one pump's calibration with its simulations as Dask tasks on the warm 2-worker cluster,
  against threads of this process: where Dask's messages cost more than they gain.
"""

from concurrent.futures import ProcessPoolExecutor
import multiprocessing
from pathlib import Path
import statistics
import sys
import tempfile
import time

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(ROOT))
from bench_sweep import wait_idle  # noqa: E402
from naive_calibrate import naive  # noqa: E402

from hydropump_ctrl.batch import DaskExecutor, InProcess, open_client  # noqa: E402
from hydropump_ctrl.ident import read_recordings  # noqa: E402
from hydropump_ctrl.ident.calibrate import calibrate, params_with  # noqa: E402
from hydropump_ctrl.ident.calibrate.fleet import calibrate_fleet  # noqa: E402
from hydropump_sim.params import load_params  # noqa: E402
from hydropump_sim.simulate import simulate  # noqa: E402
from tests import independent as ind  # noqa: E402

from common import emit, median_time, row  # noqa: E402

FREE = ('actuator.mu_a', 'actuator.P_a_bar', 'line.V_l', 'line.mu_u')
FACTORS = (1.3, 0.8, 1.45, 0.88)
CASES = {'flow and line pressure': ['line_flow', 'line_pressure'],
         'four bench sensors': ['line_flow', 'line_pressure', 'actuator_pressure']}


# The fleet's pumps: factors on config/pump.yaml's values of FREE.
FLEET = {'pump_a': FACTORS, 'pump_b': (0.85, 1.15, 0.8, 1.12), 'pump_c': (1.12, 0.88, 1.25, 0.9),
         'pump_d': (0.9, 1.1, 1.3, 1.1)}


def designs(truth) -> dict:
    """Two current staircases at two load pressures and load-pressure steps (17 s)."""
    lo, hi = truth.current_range
    stairs = ind.staircase([lo + x * (hi - lo) for x in (0.3, 0.45, 0.6, 0.4, 0.55, 0.7, 0.5)],
                           0.8)
    steps = ind.staircase([12e6, 9e6, 13e6, 10e6], 1.0)
    return {'stairs_120bar': (stairs, None),
            'stairs_80bar': (stairs, np.full(stairs.size, 8e6)),
            'load_steps': (np.full(steps.size, lo + 0.5 * (hi - lo)), steps)}


def data(folder: Path, factors=FACTORS, seed=7):
    base = load_params(ROOT / 'config' / 'pump.yaml')
    truth = params_with(base, FREE, [base.flat()[n] * f for n, f in zip(FREE, factors)])
    lo, hi = truth.current_range
    paths = []
    for k, (name, (cur, load)) in enumerate(designs(truth).items()):
        rec = ind.measure(ind.run(truth, cur, load), ind.BENCH, seed=(seed, k))
        paths.append(ind.write(folder / name, 1e-3, rec, truth.fluid.p_atm))
    t = np.arange(4000) * 1e-3
    held = ind.run(truth, lo + (hi - lo) * (0.5 + 0.25 * np.sin(
        2 * np.pi * 0.7 * np.floor(t / 0.02) * 0.02)), np.where(t < 2.0, 12e6, 9e6))
    return base, truth, read_recordings(paths), held


def held_out_error(params, run) -> tuple[float, float]:
    """Largest error on the held-out run: flow in % of V_p f_p, line pressure in bar."""
    n = run.n
    res = simulate(params, (n - 1) * run.dt, run.current, load_pressure=run.load_pressure,
                   dt_out=run.dt)
    t = np.arange(n) * run.dt
    return (100 * float(np.max(np.abs(res.q_l[:n] - run.signal('line_flow', t)))) /
            params.Q_max,
            float(np.max(np.abs(res.P_l[:n] - run.signal('line_pressure', t)))) / 1e5)


def warm(executor, fleet, base, signals) -> None:
    """One short calibration a worker: the imports and the compiled code loaded."""
    calibrate_fleet({f'warm{k}': recs[:1] for k, recs in enumerate(
        list(fleet.values())[:executor.workers])}, base, FREE[:1], executor=executor,
        signals=signals, max_nfev=2, multistart=False)


def fleet_rows(base, repeat: int = 5) -> list[dict]:
    signals = CASES['four bench sensors']
    with tempfile.TemporaryDirectory() as tmp:
        fleet, truths = {}, {}
        for p, (name, factors) in enumerate(FLEET.items()):
            _, truth, recs, _ = data(Path(tmp) / name, factors, seed=20 + p)
            fleet[name], truths[name] = recs, truth.flat()
    ways, start = {}, {}
    for workers in (1, 2):
        t0 = time.perf_counter()
        client, cluster = open_client(None, workers)
        ways[f'dask{workers}'] = DaskExecutor(client, cluster, own_client=True)
        warm(ways[f'dask{workers}'], fleet, base, signals)
        start[workers] = time.perf_counter() - t0
    # Without a cluster, in a process of its own with no Dask in it (this one hosts the
    # clusters' schedulers and nannies, whose threads would take its time): one pump after
    # the other, each with its simulations on threads; or two pumps at once, each on a thread.
    plain = ProcessPoolExecutor(1, mp_context=multiprocessing.get_context('spawn'))
    plain.submit(here, 1, {'w': fleet['pump_a'][:1]}, base, signals, FREE[:1]).result()
    times: dict[str, list[float]] = {k: [] for k in (*ways, 'here1', 'here2')}
    load = []
    try:
        # Interleaved, so that a change of the machine's load falls on every way alike.
        for _ in range(repeat):
            for name in times:
                load.append(wait_idle())
                if name.startswith('here'):
                    dt, res = plain.submit(here, int(name[-1]), fleet, base, signals).result()
                else:
                    t0 = time.perf_counter()
                    res = calibrate_fleet(fleet, base, FREE, executor=ways[name],
                                          signals=signals)
                    dt = time.perf_counter() - t0
                times[name].append(dt)
                worst = max(abs(e.value / truths[pr.name][e.name] - 1) for pr in res.pumps
                            for e in pr.calibration.estimates)
                assert worst < 0.02, (name, worst)
        t_dask = one_pump(fleet['pump_a'], base, signals, ways['dask2'])
    finally:
        for ex in reversed(ways.values()):
            ex.close()
    t_threads = plain.submit(one_pump, fleet['pump_a'], base, signals).result()
    plain.shutdown()
    t = {k: statistics.median(v) for k, v in times.items()}
    for k, v in times.items():
        print(f'fleet of {len(fleet)}, {k}: ' + ', '.join(f'{x:.2f}' for x in v)
              + f' s: median {t[k]:.2f} s')
    print(f'start-up of a local cluster with a first calibration on each worker: '
          f'{start[1]:.1f} s (1 worker), {start[2]:.1f} s (2)')
    speedup = t['dask1'] / t['dask2']
    best = min(t['here1'], t['here2'])
    # A local cluster of 2 pays from n pumps where n p (1 - 1/s) > start, s its speed-up
    # over this process's best way, p the time a pump takes here.
    gain = 1.0 - t['dask2'] / best
    cross = start[2] / (best / len(fleet) * gain) if gain > 0 else float('inf')
    note = (f'{len(fleet)} pumps x 3 bags (17 s of data each), four bench sensors; medians '
            f'of {repeat}, interleaved, each started on cores {100 * min(load):.0f}-'
            f'{100 * max(load):.0f} % idle')
    return [
        row('calibrate fleet: speed-up, 2 Dask workers vs 1', speedup, 'x', '>= 1.7',
            speedup >= 1.7, note + f'; 1 worker {t["dask1"]:.2f} s'),
        row('calibrate fleet: 2 Dask workers vs no cluster (its best way)', best / t['dask2'],
            'x', '', None, f'no cluster: one pump after the other {t["here1"]:.2f} s, two '
            f'at once on threads {t["here2"]:.2f} s'),
        row('calibrate fleet: local cluster start-up (2 workers, warm)', start[2], 's', '',
            None, 'cluster start and a first calibration on each worker'),
        row('calibrate fleet: crossover, pumps from which a local cluster pays', cross,
            'pumps', '', None, 'start-up / (time a pump here x (1 - cluster / here))'),
        row('calibrate one pump: simulations as Dask tasks (2 workers) vs threads',
            t_threads / t_dask, 'x', '', None,
            f'threads {t_threads:.2f} s, Dask {t_dask:.2f} s (below 1: the messages cost '
            'more than the tasks gain)'),
    ]


def here(threads, fleet, base, signals, free=FREE):
    """The fleet in this process on ``threads`` threads: its wall time and result."""
    t0 = time.perf_counter()
    res = calibrate_fleet(fleet, base, free, executor=InProcess(threads), signals=signals)
    return time.perf_counter() - t0, res


def one_pump(recs, base, signals, executor=None) -> float:
    """Median time of one pump's calibration on ``executor`` (default threads), warm."""
    def fit():
        calibrate(recs, base, FREE, signals=signals, executor=executor)
    fit()
    return median_time(fit, 3)[0]


# Effects config/pump.yaml leaves at zero, in the pump of the whole-command rows.
EFFECTS = {'actuator.G_leak_a': 1e-12, 'plate.F_coul_a': 50.0}


def command_rows(repeat: int = 3) -> list[dict]:
    """Whole commands as a user runs them, on bags of the pump written apart from the model
    (``tests/paper_plant.py``) with actuator leakage and plate friction: ``hydropump
    calibrate`` (process start, reading, calibration, the report with its figures and
    without) against the naive script (``naive_calibrate.py``: process start, reading, the
    fit, its params file), four parameters free and six (the effects too); interleaved,
    each started on idle cores, medians of ``repeat``."""
    import json
    import subprocess

    from tests import paper_plant
    base = load_params(ROOT / 'config' / 'pump.yaml')
    truth = params_with(base, FREE, [base.flat()[n] * f for n, f in
                                     zip(FREE, FACTORS)]).replace(EFFECTS)
    tf = truth.flat()
    signals = CASES['four bench sensors']
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        bags = []
        for k, (name, (cur, load)) in enumerate(designs(truth).items()):
            rec = ind.measure(paper_plant.run(tf, cur, load), ind.BENCH, seed=(11, k))
            bags.append(str(ind.write(tmp / 'bags' / name, 1e-3, rec, truth.fluid.p_atm)))
        tool = Path(sys.executable).parent / 'hydropump'
        for case, free in (('four free', FREE), ('six free', FREE + tuple(EFFECTS))):
            ours = [str(tool), 'calibrate', *bags, '--free', *free, '--signals', *signals,
                    '--report', str(tmp / 'report'), '--no-progress']
            cmds = {'project': ours, 'project, no figures': ours + ['--no-plots'],
                    'naive': [sys.executable, str(Path(__file__).parent / 'naive_calibrate.py'),
                              *bags, '--free', *free, '--signals', *signals, '--out',
                              str(tmp / 'naive.yaml')]}
            times: dict[str, list[float]] = {k: [] for k in cmds}
            for _ in range(repeat):
                for k, cmd in cmds.items():
                    wait_idle()
                    t0 = time.perf_counter()
                    subprocess.run(cmd, check=True, capture_output=True)
                    times[k].append(time.perf_counter() - t0)
            t = {k: statistics.median(v) for k, v in times.items()}
            result = json.loads((tmp / 'report' / 'result.json').read_text())
            mine = max(abs(v['value'] / tf[n] - 1) for n, v in result['parameters'].items())
            theirs = max(abs(load_params(tmp / 'naive.yaml').flat()[n] / tf[n] - 1)
                         for n in free)
            named = [c['parameter'] for c in result['missing_effects']]
            for k, v in times.items():
                print(f'command, {case}, {k}: ' + ', '.join(f'{x:.2f}' for x in v)
                      + f' s: median {t[k]:.2f} s')
            print(f'command, {case}: worst parameter error {100 * mine:.2f} % (naive '
                  f'{100 * theirs:.2f} %); named as missing: {", ".join(named) or "-"}')
            rows += [
                row(f'calibrate command, {case}: speed-up over the naive script',
                    t['naive'] / t['project'], 'x', '>= 2', t['naive'] / t['project'] >= 2.0,
                    f'project {t["project"]:.2f} s (no figures {t["project, no figures"]:.2f}'
                    f' s), naive {t["naive"]:.2f} s; whole processes, medians of {repeat}'),
                row(f'calibrate command, {case}: worst parameter error (naive)', 100 * mine,
                    '%', '', None, f'{100 * theirs:.2f} %; named missing: '
                    f'{", ".join(named) or "-"}'),
            ]
    return rows


def main() -> int:
    rows = command_rows()
    with tempfile.TemporaryDirectory() as tmp:
        base, truth, recs, held = data(Path(tmp))
    tf = truth.flat()
    calibrate(recs[:1], base, FREE[:1], max_nfev=2)   # compile and warm the caches
    for case, signals in CASES.items():
        t_ours, t_naive = [], []
        for _ in range(3):
            # Each started on idle cores: the project's threads would take another's load
            # more than the serial naive fit.
            wait_idle()
            t0 = time.perf_counter()
            cal = calibrate(recs, base, FREE, signals=signals)
            t_ours.append(time.perf_counter() - t0)
            wait_idle()
            t0 = time.perf_counter()
            vals, delay = naive(base, recs, signals, FREE)
            t_naive.append(time.perf_counter() - t0)
        ours = [abs(p.value / tf[p.name] - 1) for p in cal.estimates]
        theirs = [abs(v / tf[n] - 1) for n, v in zip(FREE, vals)]
        h_ours = held_out_error(cal.params, held)
        h_naive = held_out_error(params_with(base, FREE, vals), held)
        a, b = statistics.median(t_ours), statistics.median(t_naive)
        print(f'{case}: project {a:.2f} s ({", ".join(f"{t:.2f}" for t in t_ours)}), '
              f'{cal.n_simulations} simulated runs, errors '
              + ', '.join(f'{n.split(".")[1]} {100 * e:+.2f} %' for n, e in zip(FREE, ours))
              + f', delay {1e3 * cal.delays["all"]["line_flow"]:.2f} ms; held out '
              f'{h_ours[0]:.3f} % FS, {h_ours[1]:.3f} bar')
        print(f'{case}: naive {b:.2f} s ({", ".join(f"{t:.2f}" for t in t_naive)}), errors '
              + ', '.join(f'{n.split(".")[1]} {100 * e:+.2f} %' for n, e in zip(FREE, theirs))
              + f', delay {1e3 * delay:.2f} ms; held out {h_naive[0]:.3f} % FS, '
              f'{h_naive[1]:.3f} bar')
        more = max(ours) <= max(theirs) + 1e-4 and h_ours[0] <= h_naive[0] + 1e-3 \
            and h_ours[1] <= h_naive[1] + 1e-3
        rows += [
            row(f'calibrate, {case}: wall time (median of 3)', a, 's', '', None,
                f'{cal.n_simulations} simulated runs'),
            row(f'calibrate, {case}: speed-up over the naive fit', b / a, 'x', '>= 2x',
                b / a >= 2.0, f'naive {b:.2f} s'),
            row(f'calibrate, {case}: worst parameter error (naive)', 100 * max(ours), '%',
                '<= 2 %, <= naive', max(ours) <= 0.02 and more, f'{100 * max(theirs):.2f} %'),
            row(f'calibrate, {case}: held-out flow error (naive)', h_ours[0], '% FS',
                '<= 0.25', h_ours[0] <= 0.25, f'{h_naive[0]:.3f} % FS'),
            row(f'calibrate, {case}: held-out line pressure error (naive)', h_ours[1], 'bar',
                '<= 0.5', h_ours[1] <= 0.5, f'{h_naive[1]:.3f} bar'),
            row(f'calibrate, {case}: flow delay error (truth 12.4 ms)',
                abs(1e3 * cal.delays['all']['line_flow'] - 12.4), 'ms', '<= 0.2',
                abs(cal.delays['all']['line_flow'] - 0.0124) <= 2e-4,
                f'naive {abs(1e3 * delay - 12.4):.2f} ms'),
        ]
    rows += fleet_rows(base)
    emit(rows)
    return 0


if __name__ == '__main__':
    sys.exit(main())
