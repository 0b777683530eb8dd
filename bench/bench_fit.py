"""Identification speed and accuracy on the nine-record synthetic set (section V, eq. 19-20).

Nine synthetic 20 s records at 1 kHz (G0 100, tau 100 ms, t_d 55 ms; noise 0.5 % FS,
quantisation 0.25 % FS, 3 % dither at 150 Hz, staircases from a non-zero steady state),
fitted and reported by the project (robust method, then the paper's method), against a naive
baseline measured in the same run: scipy Nelder-Mead (fminsearch settings) on eq. 20 with
``scipy.signal.lsim`` of eq. 19 per evaluation, the delay applied by shifting the input in
time, from the same step seeds.

Goals: the whole run (fit and report) <= 3 s; >= 10x faster than the baseline at equal or
better accuracy.
"""

from pathlib import Path
import sys
import tempfile
import time

import numpy as np
from scipy import optimize, signal

sys.path.insert(0, str(Path(__file__).resolve().parent))
from hydropump_ctrl.ident import (  # noqa: E402
    fit_recordings,
    format_table,
    load_default_params,
    normalise,
    synthetic,
    write_report,
)
from hydropump_ctrl.ident.paper import initial_levels, step_seed  # noqa: E402

from common import emit, median_time, row  # noqa: E402

TRUTH = synthetic.Truth(100.0, 0.100, 0.055)


def naive_fit(u, y, dt):
    """Nelder-Mead on eq. 20, lsim per evaluation (the naive baseline)."""
    seed = step_seed(u, y, dt)
    u_ref, y_ref = initial_levels(u, y, dt, seed[2])
    t = np.arange(u.size) * dt
    v, z = u - u_ref, y - y_ref

    def J(th):
        G0, tau, td = th
        if not (tau > 0 and td >= 0):
            return np.inf
        u_del = np.interp(t - td, t, v, left=0.0)
        _, q, _ = signal.lsim(signal.lti([G0], [tau, 1.0]), u_del, t)
        r = z - q
        return float(r @ r)

    res = optimize.minimize(J, seed, method='Nelder-Mead',
                            options={'xatol': 1e-4, 'fatol': 1e-4, 'maxiter': 600,
                                     'maxfev': 600})
    return res.x, res.nfev


def errors(estimates):
    """Pooled absolute error and per-set rms error of each parameter."""
    est = np.asarray(estimates)
    truth = np.array([TRUTH.G0, TRUTH.tau, TRUTH.td])
    return np.abs(est.mean(axis=0) - truth), np.sqrt(np.mean((est - truth) ** 2, axis=0))


def main():
    recs, _ = synthetic.paper_set(seed=5)
    params = load_default_params()
    data = [normalise(r, params) for r in recs]
    fit_recordings(recs[:1], joint=False)       # warm caches outside the timing

    t_fit, runs = median_time(lambda: fit_recordings(recs, params=params), repeat=5)
    ident = fit_recordings(recs, params=params)
    print(format_table(ident))
    print(f'robust fit of nine records: median {t_fit:.2f} s of {len(runs)} runs')

    with tempfile.TemporaryDirectory() as tmp:
        def whole():
            res = fit_recordings(recs, params=params)
            format_table(res)
            write_report(res, tmp, params=params)
        t_whole, _ = median_time(whole, repeat=3)
    print(f'fit + report (JSON, Markdown, Fig. 5 and 6 of all nine sets): median '
          f'{t_whole:.2f} s of 3 runs')

    t_paper, _ = median_time(lambda: fit_recordings(recs, method='paper', params=params),
                             repeat=5)
    paper = fit_recordings(recs, method='paper', params=params)

    base_times, base_est, base_nfev = [], [], []
    for u, y in data:
        t0 = time.perf_counter()
        x, nfev = naive_fit(u, y, recs[0].dt)
        base_times.append(time.perf_counter() - t0)
        base_est.append(x)
        base_nfev.append(nfev)
    t_base = float(np.sum(base_times))
    t_base_med = float(np.median(base_times))
    print(f'naive baseline: {t_base:.1f} s for nine records (median {t_base_med:.2f} s per '
          f'record, {int(np.median(base_nfev))} evaluations)')

    ours = [[f.G0, f.tau, f.td] for f in ident.sets]
    pap = [[f.G0, f.tau, f.td] for f in paper.sets]
    (e_ours, r_ours), (e_base, r_base), (e_pap, r_pap) = (errors(ours), errors(base_est),
                                                           errors(pap))
    for name, e, r in (('robust', e_ours, r_ours), ('paper', e_pap, r_pap),
                       ('baseline', e_base, r_base)):
        print(f'{name:9s} pooled error G0 {e[0]:.3f}, tau {1e3 * e[1]:.3f} ms, t_d '
              f'{1e3 * e[2]:.3f} ms; per-set rms G0 {r[0]:.3f}, tau {1e3 * r[1]:.3f} ms, '
              f't_d {1e3 * r[2]:.3f} ms')
    speed = t_base / t_fit
    per_rec = t_base_med / (t_fit / len(recs))
    better = bool(np.all(r_ours <= r_base * 1.0001))
    emit([
        row('robust fit, nine records (median of 5)', t_fit, 's', '<= 3', t_fit <= 3.0),
        row('whole run: fit + report with all figures (median of 3)', t_whole, 's',
            '<= 3', t_whole <= 3.0),
        row('paper method, nine records (median of 5)', t_paper, 's'),
        row('naive baseline (Nelder-Mead + lsim), nine records', t_base, 's'),
        row('speed-up vs naive baseline, whole set', speed, 'x', '>= 10', speed >= 10),
        row('speed-up vs naive baseline, median per record', per_rec, 'x', '>= 10',
            per_rec >= 10),
        row('pooled |dG0|, robust', e_ours[0], '%', '<= 0.5', bool(e_ours[0] <= 0.5)),
        row('pooled |dtau|, robust', 1e3 * e_ours[1], 'ms', '<= 2', bool(e_ours[1] <= 2e-3)),
        row('pooled |dt_d|, robust', 1e3 * e_ours[2], 'ms', '<= 1', bool(e_ours[2] <= 1e-3)),
        row('pooled |dG0|, baseline', e_base[0], '%'),
        row('pooled |dtau|, baseline', 1e3 * e_base[1], 'ms'),
        row('pooled |dt_d|, baseline', 1e3 * e_base[2], 'ms'),
        row('per-set rms t_d error, robust', 1e3 * r_ours[2], 'ms'),
        row('per-set rms t_d error, baseline', 1e3 * r_base[2], 'ms'),
        row('per-set rms errors robust <= baseline (G0, tau, t_d)', float(better), 'bool',
            '== 1', better),
    ])


if __name__ == '__main__':
    main()
