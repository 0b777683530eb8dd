"""The whole of eq. 16 from recordings of the fine model: small current steps both ways
around one operating point, and load-pressure steps at a held current. Checked against the
paper's closed forms (the zero of eq. 17, S_a / b_p) and the fine model's linearisation at
the same operating point."""

import json
import subprocess
import sys

import numpy as np
import pytest

from hydropump_ctrl.ident import recording_to_bag
from hydropump_ctrl.ident.matrix import fit_matrix, linear_elements
from hydropump_ctrl.ident.synthetic import plant_recording
from hydropump_sim.paper import zero_time_constant
from hydropump_sim.params import load_params

from ..conftest import PUMP_YAML

N = 800   # samples per level (0.8 s at 1 kHz, eight time constants)


@pytest.fixture(scope='module')
def records(params):
    lo, hi = params.current_range
    mid, d = 0.5 * (lo + hi), 0.02 * (hi - lo)
    cur = np.concatenate([np.full(N, mid if k % 2 == 0 else mid + d) for k in range(9)])
    stair = plant_recording(params, cur, name='stair')
    pu = np.concatenate([np.full(N, params.line.P_u - (0.0 if k % 2 == 0 else 2.0e5))
                         for k in range(5)])
    load = plant_recording(params, np.full(pu.size, mid + d / 2), load_pressure=pu,
                           name='load')
    return [stair, load], mid + d / 2


def test_every_element_matches_the_linearisation(params, records):
    recs, current = records
    fits = fit_matrix(recs, params=params)
    lin = linear_elements(params, current)
    assert set(fits) == {'G21_up', 'G21_down', 'G11', 'G12'}
    for kind, e in fits.items():
        for name in ('G0', 'tau', 'tau_l'):
            if name in e.values and name in lin[kind]:
                assert abs(e.values[name] / lin[kind][name] - 1) < 0.02, (kind, name)
        assert all(np.isfinite(v) for k, v in e.stderr.items() if k in e.values)
        assert e.fit_percent > 99.0
    # The zero of eq. 17 on the falling branch: S_a / b_p.
    assert abs(fits['G21_down'].values['tau_z'] - zero_time_constant(params)) < 1e-3
    # The closed forms: the static gain of eq. 19 is phi_s b_p / K_a on both branches, and a
    # load-pressure step passes to the line one to one.
    g = params.spool.phi_s * params.b_p / params.spool.K_a
    for kind in ('G21_up', 'G21_down'):
        assert abs(fits[kind].values['G0'] / g - 1) < 0.005
    assert abs(fits['G12'].values['G0'] - 1.0) < 0.005


def test_fit_matrix_on_the_command_line(records, tmp_path):
    recs, _ = records
    paths = [str(recording_to_bag(r, tmp_path / r.name)) for r in recs]
    proc = subprocess.run([sys.executable, '-m', 'hydropump_ctrl.cli', 'fit', '--matrix',
                           *paths, '--params', str(PUMP_YAML), '--json', '--no-progress'],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    res = json.loads(proc.stdout)
    el = res['elements']['G21_down']
    assert set(el['values']) >= {'G0', 'tau', 'tau_z'} and el['linearisation']['tau_z'] > 0
    # A bag with no step at all is refused with one line.
    flat = plant_recording(load_params(PUMP_YAML), np.full(500, 0.5), name='flat')
    path = recording_to_bag(flat, tmp_path / 'flat')
    proc = subprocess.run([sys.executable, '-m', 'hydropump_ctrl.cli', 'fit', '--matrix',
                           str(path), '--no-progress'], capture_output=True, text=True,
                          timeout=300)
    assert proc.returncode == 2 and 'no element of eq. 16 can be fitted' in proc.stderr
    assert 'Traceback' not in proc.stderr
