"""Plant library speed and accuracy: 10 s of the fine model, step plus sine current and an
aperture step, Rodas4 (the project's stepper) against scipy Radau at rtol 1e-9.

Goals: >= 500x real time offline and >= 300x stepped at 1 kHz on one core, with <= 0.1 %
of V_p f_p error on q_l. The sine makes the input change at every increment, so offline
steps cannot run free of them here (bench_circuit's plant rows, of steps, can).
"""

from pathlib import Path
import sys

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from hydropump_sim import load_params, simulate, Simulator  # noqa: E402
from hydropump_sim.params import default_params_path  # noqa: E402
from hydropump_sim.scaling import current_for_displacement  # noqa: E402

from common import emit, median_time, row  # noqa: E402

DURATION = 10.0


def main():
    p = load_params(default_params_path())
    I0, I1 = current_for_displacement(p, [0.4, 0.6])
    amp = 0.1 * (p.current_range[1] - p.current_range[0])

    def current(t):
        t = np.asarray(t)
        return np.where(t < 1.0, I0, I1) + amp * np.sin(2 * np.pi * 2.0 * t) * (t >= 3.0)

    def aperture(t):
        return np.where(np.asarray(t) < 6.0, 0.5, 0.6)

    kw = dict(current=current, aperture=aperture)
    simulate(p, 0.01, I0)  # compile or load the cache outside the timing
    t_rodas, runs = median_time(lambda: simulate(p, DURATION, **kw), repeat=7)
    fast = simulate(p, DURATION, **kw)
    print(f'Rodas4: median {t_rodas * 1e3:.1f} ms of {len(runs)} runs '
          f'({fast.stats["accepted"]} steps, {fast.stats["rejected"]} rejected)')
    t_radau, runs_r = median_time(lambda: simulate(p, DURATION, method='radau', rtol=1e-9,
                                                   **kw), repeat=3)
    ref = simulate(p, DURATION, method='radau', rtol=1e-9, **kw)
    print(f'Radau rtol 1e-9: median {t_radau:.1f} s of {len(runs_r)} runs')
    err = float(np.max(np.abs(fast.q_l - ref.q_l)) / p.Q_max * 100.0)

    sim = Simulator(p, dt=1e-3)
    n = int(DURATION / 1e-3)
    tk = np.arange(n) * 1e-3
    cur_k, ap_k = current(tk).tolist(), aperture(tk).tolist()

    def stepper():
        sim.reset()
        for k in range(n):
            sim.set_input('pump.current', cur_k[k])
            sim.set_input('load.aperture', ap_k[k])
            sim.step()
    t_step, _ = median_time(stepper, repeat=5)
    rtf = DURATION / t_rodas
    emit([
        row('real-time factor, simulate() (Rodas4)', rtf, 'x', '>= 500', rtf >= 500),
        row('real-time factor, Simulator.step() at 1 kHz', DURATION / t_step, 'x', '>= 300',
            DURATION / t_step >= 300),
        row('max |q_l - q_l,Radau 1e-9|', err, '% V_p f_p', '<= 0.1', err <= 0.1),
        row('speed ratio Rodas4 / Radau 1e-9 (same run)', t_radau / t_rodas, 'x'),
    ])


if __name__ == '__main__':
    main()
