"""The naive calibration a user would write in an afternoon: the baseline of
``bench_calibrate.py``, as a function and as a command.

scipy ``least_squares`` around ``hydropump_sim.simulate()``: its own 2-point differences, the
free parameters as log factors on their start (a parameter at zero starts at a thousandth of
its range), one flow-meter delay from a grid search at the start, each signal weighted by
its noise from second differences; serial, BLAS on one thread as for the project. The bags
are read with the suite's reader, as a user of the suite would.

As a command (timed whole by ``bench_calibrate.py``: process start, reading, the fit, the
params file written)::

    python bench/naive_calibrate.py --free actuator.mu_a line.V_l --out fit.yaml BAG...
"""

import argparse
from pathlib import Path
import sys

import numpy as np
from scipy.optimize import least_squares

ROOT = Path(__file__).resolve().parents[1]

OUTPUT = {'line_flow': 'q_l', 'line_pressure': 'P_l', 'actuator_pressure': 'P_a'}
SIGNALS = ['line_flow', 'line_pressure', 'actuator_pressure']


def naive(base, recs, signals, free):
    """The baseline (see the module): the fitted values and the flow delay."""
    from hydropump_ctrl.ident.calibrate import params_with
    from hydropump_ctrl.ident.fit import blas_single_threaded
    from hydropump_sim.schema import spec_map
    from hydropump_sim.simulate import simulate

    p_atm = base.fluid.p_atm
    data = []
    for r in recs:
        cur = np.asarray(r['solenoid_current'])
        load = np.asarray(r['load_pressure']) - p_atm
        load = np.append(load[1:], load[-1])        # the sample of the step that ended there
        meas = {s: np.asarray(r[s]) - (p_atm if 'pressure' in s else 0.0) for s in signals}
        sig = {s: np.std(np.diff(v, 2)) / np.sqrt(6.0) for s, v in meas.items()}
        data.append((cur, load, meas, sig, r.dt))
    specs = spec_map(type(base))
    theta0 = np.array([base.flat()[n] or 1e-3 * specs[n].range[1] for n in free])

    def sims(x):
        p = params_with(base, free, theta0 * np.exp(x))
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

    @blas_single_threaded
    def fit():
        grid = np.arange(0.0, 0.1, 5e-4)
        start = sims(np.zeros(len(free)))
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

        lo = np.log(np.maximum([specs[n].range[0] for n in free], 1e-300) / theta0)
        hi = np.log(np.array([specs[n].range[1] for n in free]) / theta0)
        sol = least_squares(resid, np.zeros(len(free)), bounds=(np.maximum(lo, -6.0),
                                                                np.minimum(hi, 6.0)))
        return theta0 * np.exp(sol.x), delay
    return fit()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('bags', nargs='+')
    ap.add_argument('--free', nargs='+', required=True)
    ap.add_argument('--signals', nargs='+', default=SIGNALS)
    ap.add_argument('--params', default=str(ROOT / 'config' / 'pump.yaml'))
    ap.add_argument('--out', required=True)
    args = ap.parse_args(argv)
    from hydropump_ctrl.ident import read_recordings
    from hydropump_ctrl.ident.calibrate import params_with
    from hydropump_sim.params import load_params
    from hydropump_sim.schema import dump_ros_yaml
    base = load_params(args.params)
    recs = read_recordings(args.bags)
    values, delay = naive(base, recs, args.signals, args.free)
    fitted = params_with(base, args.free, values)
    Path(args.out).write_text(dump_ros_yaml(fitted.flat()), encoding='utf-8')
    print(', '.join(f'{n} = {v:.6g}' for n, v in zip(args.free, values))
          + f'; flow delay {1e3 * delay:.2f} ms')
    return 0


if __name__ == '__main__':
    sys.path.insert(0, str(ROOT))
    sys.exit(main())
