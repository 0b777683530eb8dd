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
held-out error). Medians of three runs each.
"""

from pathlib import Path
import statistics
import sys
import tempfile
import time

import numpy as np
from scipy.optimize import least_squares

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(ROOT))
from hydropump_ctrl.ident import read_recordings  # noqa: E402
from hydropump_ctrl.ident.calibrate import calibrate, params_with  # noqa: E402
from hydropump_ctrl.ident.fit import blas_single_threaded  # noqa: E402
from hydropump_sim.params import load_params  # noqa: E402
from hydropump_sim.simulate import simulate  # noqa: E402
from tests import independent as ind  # noqa: E402

from common import emit, row  # noqa: E402

FREE = ('actuator.mu_a', 'actuator.P_a_bar', 'line.V_l', 'line.mu_u')
FACTORS = (1.3, 0.8, 1.45, 0.88)
OUTPUT = {'line_flow': 'q_l', 'line_pressure': 'P_l', 'actuator_pressure': 'P_a'}
CASES = {'flow and line pressure': ['line_flow', 'line_pressure'],
         'four bench sensors': ['line_flow', 'line_pressure', 'actuator_pressure']}


def data(folder: Path):
    base = load_params(ROOT / 'config' / 'pump.yaml')
    truth = params_with(base, FREE, [base.flat()[n] * f for n, f in zip(FREE, FACTORS)])
    lo, hi = truth.current_range
    stairs = ind.staircase([lo + x * (hi - lo) for x in (0.3, 0.45, 0.6, 0.4, 0.55, 0.7, 0.5)],
                           0.8)
    steps = ind.staircase([12e6, 9e6, 13e6, 10e6], 1.0)
    designs = {'stairs_120bar': (stairs, None), 'stairs_80bar': (stairs, np.full(stairs.size,
                                                                                  8e6)),
               'load_steps': (np.full(steps.size, lo + 0.5 * (hi - lo)), steps)}
    paths = []
    for k, (name, (cur, load)) in enumerate(designs.items()):
        rec = ind.measure(ind.run(truth, cur, load), ind.BENCH, seed=(7, k))
        paths.append(ind.write(folder / name, 1e-3, rec, truth.fluid.p_atm))
    t = np.arange(4000) * 1e-3
    held = ind.run(truth, lo + (hi - lo) * (0.5 + 0.25 * np.sin(
        2 * np.pi * 0.7 * np.floor(t / 0.02) * 0.02)), np.where(t < 2.0, 12e6, 9e6))
    return base, truth, read_recordings(paths), held


@blas_single_threaded
def naive(base, recs, signals):
    """The baseline (see the module): about sixty lines a user would write."""
    p_atm = base.fluid.p_atm
    data = []
    for r in recs:
        cur = np.asarray(r['solenoid_current'])
        load = np.asarray(r['load_pressure']) - p_atm
        load = np.append(load[1:], load[-1])        # the sample of the step that ended there
        meas = {s: np.asarray(r[s]) - (p_atm if 'pressure' in s else 0.0) for s in signals}
        sig = {s: np.std(np.diff(v, 2)) / np.sqrt(6.0) for s, v in meas.items()}
        data.append((cur, load, meas, sig, r.dt))
    theta0 = np.array([base.flat()[n] for n in FREE])

    def sims(x):
        p = params_with(base, FREE, theta0 * np.exp(x))
        out = []
        for cur, load, _, _, dt in data:
            res = simulate(p, (cur.size - 1) * dt, cur, load_pressure=load, dt_out=dt)
            out.append({s: getattr(res, OUTPUT[s])[:cur.size] for s in signals})
        return out

    def shift(y, d, dt):
        t = np.arange(y.size) * dt
        return np.interp(t - d, t, y)

    def flow_sse(out, d):
        return sum(float(np.sum((shift(o['line_flow'], d, dt) - m['line_flow']) ** 2))
                   for o, (_, _, m, _, dt) in zip(out, data))

    grid = np.arange(0.0, 0.1, 5e-4)
    start = sims(np.zeros(len(FREE)))
    delay = float(grid[int(np.argmin([flow_sse(start, d) for d in grid]))])

    def resid(x):
        try:
            out = sims(x)
        except Exception:   # a trial point the model cannot simulate
            return np.full(sum(c.size * len(signals) for c, *_ in data), 1e3)
        res = []
        for o, (_, _, m, sg, dt) in zip(out, data):
            for s in signals:
                y = shift(o[s], delay, dt) if s == 'line_flow' else o[s]
                res.append((y - m[s]) / sg[s])
        return np.concatenate(res)

    sol = least_squares(resid, np.zeros(len(FREE)), bounds=(-1.5, 1.5))
    return theta0 * np.exp(sol.x), delay


def held_out_error(params, run) -> tuple[float, float]:
    """Largest error on the held-out run: flow in % of V_p f_p, line pressure in bar."""
    n = run.n
    res = simulate(params, (n - 1) * run.dt, run.current, load_pressure=run.load_pressure,
                   dt_out=run.dt)
    t = np.arange(n) * run.dt
    return (100 * float(np.max(np.abs(res.q_l[:n] - run.signal('line_flow', t)))) /
            params.Q_max,
            float(np.max(np.abs(res.P_l[:n] - run.signal('line_pressure', t)))) / 1e5)


def main() -> int:
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        base, truth, recs, held = data(Path(tmp))
    tf = truth.flat()
    calibrate(recs[:1], base, FREE[:1], max_nfev=2)   # compile and warm the caches
    for case, signals in CASES.items():
        t_ours, t_naive = [], []
        for _ in range(3):
            t0 = time.perf_counter()
            cal = calibrate(recs, base, FREE, signals=signals)
            t_ours.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            vals, delay = naive(base, recs, signals)
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
    emit(rows)
    return 0


if __name__ == '__main__':
    sys.exit(main())
