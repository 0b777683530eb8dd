"""Calibration speed and accuracy: four free plant parameters from three bags.

Three recordings of the fine model with the usual free set perturbed (``actuator.mu_a``
x1.25, ``actuator.P_a_bar`` x0.85, ``line.V_l`` x1.35, ``line.mu_u`` x0.9), 14 s of data at
1 kHz in all (a staircase up, staircases at a lower load pressure, load-pressure steps: the
three that determine the four, docs/experiment_design.md), through the bench sensor chain
without dither (noise, quantisation, the 55 ms flow delay). The start is config/pump.yaml.

- **The project**: ``calibrate()`` (trust-region least squares in log coordinates, forward-
  difference sensitivities of whole simulations run in parallel processes, the delays solved
  inside by variable projection, so they cost no simulation).
- **The naive baseline**, measured in the same run: scipy ``least_squares`` with its own
  finite differences (``2-point``) around ``simulate()``, the parameters scaled by their start
  values and one delay per signal as extra unknowns, the same noise weights.

Goal: at most 1 s; at least 2x faster than the baseline at equal accuracy.
"""

from pathlib import Path
import statistics
import sys
import time

import numpy as np
from scipy.optimize import least_squares

sys.path.insert(0, str(Path(__file__).resolve().parent))
from hydropump_ctrl.ident.calibrate import (  # noqa: E402
    calibrate,
    delayed,
    experiment_from,
    params_with,
    simulate_experiment,
    WORKERS,
)
from hydropump_ctrl.ident.design import candidate_inputs  # noqa: E402
from hydropump_ctrl.ident.synthetic import plant_recording  # noqa: E402
from hydropump_sim.errors import HydropumpError  # noqa: E402
from hydropump_sim.params import load_params  # noqa: E402
from hydropump_sim.sensors import load_profile, SensorProfile  # noqa: E402

from common import emit, row  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
FREE = ('actuator.mu_a', 'actuator.P_a_bar', 'line.V_l', 'line.mu_u')
FACTORS = (1.25, 0.85, 1.35, 0.9)


def data():
    base = load_params(ROOT / 'config' / 'pump.yaml')
    truth = params_with(base, FREE, [base.flat()[n] * f for n, f in zip(FREE, FACTORS)])
    sensors = load_profile(ROOT / 'config' / 'bench.yaml').sensors
    recs = []
    for k, (name, inp) in enumerate(candidate_inputs(truth, dwell=0.8).items()):
        if k == 1:
            continue   # three bags: up, at a lower load pressure, load-pressure steps
        recs.append(plant_recording(truth, inp['current'], load_pressure=inp['load_pressure'],
                                    profile=SensorProfile(sensors, seed=k + 1), name=name))
    return base, truth, recs


def naive(base, recs):
    """least_squares with 2-point differences around simulate(); delays as unknowns."""
    exps = [experiment_from(r, base) for r in recs]
    signals = sorted({s for e in exps for s in e.measured})
    theta0 = np.array([base.flat()[n] for n in FREE])
    n = len(FREE)

    def fun(x):
        try:
            params = params_with(base, FREE, theta0 * x[:n])
        except HydropumpError:
            return np.full(sum(e.n * len(e.measured) for e in exps), 1e6)
        d = dict(zip(signals, x[n:]))
        out = []
        for e in exps:
            try:
                sim = simulate_experiment(params, e)
            except HydropumpError:
                return np.full(sum(e.n * len(e.measured) for e in exps), 1e6)
            for s in e.measured:
                r = (delayed(sim[s], d[s], e.dt) - e.measured[s]) / e.sigma[s]
                out.append(np.where(np.isfinite(r), r, 0.0))
        return np.concatenate(out)

    x0 = np.concatenate([np.ones(n), np.full(len(signals), 0.01)])
    lo = np.concatenate([np.full(n, 0.2), np.zeros(len(signals))])
    hi = np.concatenate([np.full(n, 5.0), np.full(len(signals), 0.25)])
    sol = least_squares(fun, x0, bounds=(lo, hi), method='trf', jac='2-point', max_nfev=60)
    return theta0 * sol.x[:n], sol.nfev


def errors(values, truth):
    return [abs(v / truth.flat()[nm] - 1.0) for nm, v in zip(FREE, values)]


def main() -> int:
    base, truth, recs = data()
    dur = sum(r.duration for r in recs)
    print(f'{len(recs)} recordings, {dur:.1f} s of data at 1 kHz; {WORKERS} worker processes')
    calibrate(recs[:1], base, FREE[:1], max_nfev=2)   # compile and warm the caches
    ours, ours_err = [], None
    for _ in range(3):
        t0 = time.perf_counter()
        cal = calibrate(recs, base, FREE)
        ours.append(time.perf_counter() - t0)
        ours_err = errors([p.value for p in cal.estimates], truth)
    base_t, base_err = [], None
    for _ in range(2):
        t0 = time.perf_counter()
        vals, nfev = naive(base, recs)
        base_t.append(time.perf_counter() - t0)
        base_err = errors(vals, truth)
    t_ours, t_base = statistics.median(ours), statistics.median(base_t)
    print(f'project: {t_ours:.2f} s (runs {", ".join(f"{t:.2f}" for t in ours)}), '
          f'{cal.n_simulations} simulations, worst error {100 * max(ours_err):.2f} %')
    print(f'baseline: {t_base:.2f} s (runs {", ".join(f"{t:.2f}" for t in base_t)}), '
          f'{nfev} evaluations of 3 simulations, worst error {100 * max(base_err):.2f} %')
    emit([
        row('calibrate 4 params, 3 bags (median of 3)', t_ours, 's', '<= 1 s', t_ours <= 1.0),
        row('speed-up over least_squares 2-point around simulate()', t_base / t_ours, 'x',
            '>= 2x', t_base / t_ours >= 2.0),
        row('worst parameter error, project', 100 * max(ours_err), '%', '<= 2 %',
            max(ours_err) <= 0.02),
        row('worst parameter error, baseline', 100 * max(base_err), '%', '', None),
    ])
    return 0


if __name__ == '__main__':
    sys.exit(main())
