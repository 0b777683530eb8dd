"""Controller compute time per update as a fraction of the update period (200 Hz: 5 ms).

The controllers are replayed on the measurements of a recorded closed-loop run (fine model,
bench sensors, a flow step, then margin mode with an aperture step), so every branch of the
code runs: estimator with its delay line and predictor, reference generator, line estimator,
limits. Each figure is the median over repeated replays of the mean time per update; the 99th
percentile of single updates shows the worst ticks. The PI, measured in the same run, is the
baseline of the ratio.

Goal: EMC <= 10 % of the period.
"""

from pathlib import Path
import statistics
import sys
import time

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from hydropump_ctrl.control.emc import EMCController  # noqa: E402
from hydropump_ctrl.control.pi import PIController  # noqa: E402
from hydropump_ctrl.control.schema import load_config  # noqa: E402
from hydropump_ctrl.experiments.closed_loop import Event, run_closed_loop  # noqa: E402
from hydropump_sim import load_params  # noqa: E402
from hydropump_sim.params import default_params_path  # noqa: E402
from hydropump_sim.sensors import load_profile  # noqa: E402

from common import emit, median_time, row  # noqa: E402

REPEAT = 7


def recorded_measurements(params, profile, cfg):
    """Measurements and modes of a 2 s run: flow step, switch to margin, aperture step."""
    FS = params.Q_max
    events = [Event(0.2, 'reference', 0.7 * FS, 'flow'), Event(1.0, 'mode', 'margin'),
              Event(1.5, 'aperture', 0.6)]
    res = run_closed_loop(EMCController(cfg), 2.0, events, params=params, profile=profile,
                          start_flow=0.3 * FS, mode='flow', settle=0.1)
    names = list(res.meas)
    rows = [{n: float(res.meas[n][k]) for n in names} for k in range(res.t_ctrl.size)]
    return res.t_ctrl, rows, res.mode, res.info['I0']


def replay(make, t, meas, modes, I0, T, with_state=False):
    """One replay; returns the per-update times [s] (with ``state()`` for a ~/state topic)."""
    c = make()
    c.set_mode(modes[0])
    c.reset(I0, meas[0])
    out = np.empty(len(t))
    clock = time.perf_counter
    for k in range(len(t)):
        if modes[k] != c.mode:
            c.set_mode(modes[k], hold=True)
        t0 = clock()
        c.update(t[k], T, meas[k])
        if with_state:
            c.state()
        out[k] = clock() - t0
    return out


def main():
    plant = default_params_path()
    params = load_params(plant)
    profile = load_profile(plant.with_name('bench.yaml'))
    cfg = load_config(plant.with_name('controller.yaml'), current_limits=params.I_limits)
    T = cfg.period
    t, meas, modes, I0 = recorded_measurements(params, profile, cfg)
    results = {}
    for name, make in (('EMC', lambda: EMCController(cfg)), ('PI', lambda: PIController(cfg))):
        replay(make, t, meas, modes, I0, T)   # warm caches outside the timing
        per_update = []

        def run(make=make, per_update=per_update):
            per_update.append(replay(make, t, meas, modes, I0, T))
        total, _ = median_time(run, repeat=REPEAT)
        ticks = np.concatenate(per_update)
        mean = statistics.median(float(np.mean(x)) for x in per_update)
        flow = statistics.median(float(np.mean(x[np.array(modes) == 'flow']))
                                 for x in per_update)
        margin = statistics.median(float(np.mean(x[np.array(modes) == 'margin']))
                                   for x in per_update)
        with_state, _ = median_time(lambda make=make: replay(make, t, meas, modes, I0, T, True),
                                    repeat=REPEAT)
        results[name] = (mean, flow, margin, float(np.percentile(ticks, 99)),
                         with_state / len(t))
        print(f'{name}: {len(t)} updates per replay, median replay {total * 1e3:.1f} ms; '
              f'mean {mean * 1e6:.1f} us/update (flow {flow * 1e6:.1f}, margin '
              f'{margin * 1e6:.1f}), p99 {results[name][3] * 1e6:.1f} us')
    emc, pi = results['EMC'], results['PI']
    emit([
        row('EMC compute per update / period (200 Hz)', 100 * emc[0] / T, '%', '<= 10',
            100 * emc[0] / T <= 10.0),
        row('EMC, flow mode, per update / period', 100 * emc[1] / T, '%', '<= 10',
            100 * emc[1] / T <= 10.0),
        row('EMC, margin mode (shadow estimator), per update / period', 100 * emc[2] / T,
            '%', '<= 10', 100 * emc[2] / T <= 10.0),
        row('EMC, 99th percentile of single updates / period', 100 * emc[3] / T, '%'),
        row('EMC, update + state() per tick / period', 100 * emc[4] / T, '%', '<= 10',
            100 * emc[4] / T <= 10.0),
        row('PI compute per update / period', 100 * pi[0] / T, '%'),
        row('ratio EMC / PI (same run)', emc[0] / pi[0], 'x'),
    ])


if __name__ == '__main__':
    main()
