"""Draw docs/img/operating_map.png and docs/img/dither_sensitivity.png and print their
figures: the plant's eq. 19 over load pressure and displacement, and the growing-flow time
constant against dither amplitude and frequency (noise-free fine model, config/pump.yaml).
Run: ``.venv/bin/python docs/draw_maps.py`` (about 10 s)."""

from pathlib import Path

import numpy as np

from hydropump_ctrl.experiments.maps import (
    dither_sensitivity,
    operating_map,
    plot_dither_sensitivity,
    plot_operating_map,
    spool_resonance,
)
from hydropump_sim.params import load_params

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    params = load_params(ROOT / 'config' / 'pump.yaml')
    m = operating_map(params, [8.0e6, 1.2e7, 1.6e7], [0.2, 0.35, 0.5, 0.65, 0.8])
    plot_operating_map(m, ROOT / 'docs' / 'img' / 'operating_map.png')
    s = dither_sensitivity(params, [0.0, 0.004, 0.008, 0.012],
                           [80.0, 120.0, 140.0, 153.0, 170.0, 200.0, 300.0])
    plot_dither_sensitivity(s, ROOT / 'docs' / 'img' / 'dither_sensitivity.png',
                            spool_resonance(params))
    np.set_printoptions(precision=1, suppress=True)
    print('load pressures [bar]', m['load_pressure'] / 1e5, 'displacements', m['displacement'])
    print('tau up [ms]\n', 1e3 * m['tau_up'])
    print('tau down [ms]\n', 1e3 * m['tau_down'])
    print('G0 [%]\n', m['G0'])
    print('dither amplitudes [mA]', 1e3 * s['amplitude'], 'frequencies', s['frequency'])
    print('tau up [ms]\n', 1e3 * s['tau_up'])
    print('G0 [%]\n', s['G0'])
    print(f'spool resonance {spool_resonance(params):.1f} Hz')


if __name__ == '__main__':
    main()
