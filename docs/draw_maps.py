"""Draw docs/img/operating_map.png and docs/img/dither_sensitivity.png and print their
figures: the plant's eq. 19 over load pressure and displacement, and the growing-flow time
constant against dither amplitude and frequency (noise-free fine model, config/pump.yaml).
Run: ``.venv/bin/python docs/draw_maps.py`` (about 10 s)."""

from pathlib import Path

import numpy as np

from hydropump_ctrl.demo.maps import draw_figures, spool_resonance
from hydropump_sim.params import load_params

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    params = load_params(ROOT / 'config' / 'pump.yaml')
    m, s = draw_figures(params, ROOT / 'docs' / 'img', 'fine')
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
