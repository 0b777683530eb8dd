"""The calibration cycle of docs/identification.md, run verbatim: the block between
``<!-- cycle -->`` and ``<!-- /cycle -->`` is executed line by line by a shell, as a user
pastes it, in a folder with ``config/`` and a params file of the user's own pump
(``my_pump.yaml``, 10-30 % from config/pump.yaml on the four usual parameters).

The truth is that file, which the simulator node runs with the bench's sensors (noise,
quantisation, the 55 ms flow delay, the 400 Hz dither); that the calibration holds on data
this code did not make is tests/unit/test_calibrate.py's. Here: every command works from the
docs alone, and the cycle determines what the docs say it determines."""

import json
import os
from pathlib import Path
import re
import signal
import subprocess
import sys

import pytest
import yaml

from hydropump_ctrl.ident.calibrate import params_with
from hydropump_sim.params import load_params
from hydropump_sim.schema import dump_ros_yaml

from ..conftest import ROOT

pytestmark = [pytest.mark.ros, pytest.mark.slow]

FREE = ('actuator.mu_a', 'actuator.P_a_bar', 'line.V_l', 'line.mu_u')
FACTORS = (1.2, 0.85, 1.3, 0.9)


def documented_commands() -> list[str]:
    text = (ROOT / 'docs' / 'identification.md').read_text()
    block = re.search(r'<!-- cycle -->\n```bash\n(.*?)```\n<!-- /cycle -->', text, re.S)
    assert block, 'docs/identification.md has no cycle block'
    return [ln for ln in block.group(1).splitlines() if ln.strip()]


def test_the_documented_cycle_runs_verbatim(tmp_path, ros_domain):
    base = load_params(ROOT / 'config' / 'pump.yaml')
    truth = params_with(base, FREE, [base.flat()[n] * f for n, f in zip(FREE, FACTORS)])
    (tmp_path / 'my_pump.yaml').write_text(dump_ros_yaml(truth.flat()))
    (tmp_path / 'config').symlink_to(ROOT / 'config')
    env = dict(os.environ, ROS_DOMAIN_ID=str(ros_domain),
               PATH=f'{Path(sys.executable).parent}:{os.environ["PATH"]}')
    script = 'set -e\n' + '\n'.join(documented_commands()) + '\n'
    proc = subprocess.Popen(['bash', '-c', script], cwd=tmp_path, env=env, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            start_new_session=True)
    try:
        out, _ = proc.communicate(timeout=300)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGINT)
        out, _ = proc.communicate(timeout=30)
        pytest.fail(f'the cycle overran 300 s:\n{out[-3000:]}')
    assert proc.returncode == 0, out[-4000:]
    assert 'Traceback' not in out
    # record: one bag per experiment, the held-out one named.
    listing = yaml.safe_load((tmp_path / 'bags' / 'record.yaml').read_text())
    assert 'sine_load_step' in out and 'held out: sine_load_step' in out, listing
    # calibrate: what the docs say the campaign determines, within 2 %, well determined.
    result = json.loads((tmp_path / 'out' / 'calibration' / 'result.json').read_text())
    cal = load_params(tmp_path / 'calibrated.yaml')
    tf = truth.flat()
    for n in FREE:
        p = result['parameters'][n]
        assert p['well_determined'], (n, p)
        assert abs(cal.flat()[n] / tf[n] - 1) < 0.02, (n, cal.flat()[n], tf[n])
        assert p['ci95'][0] <= p['value'] <= p['ci95'][1]
    assert abs(result['delays_s']['all']['line_flow'] - 0.055) < 2e-4
    assert not result['weak_directions'] and not result['held_directions']
    # validate: the held-out bag explained to its noise, in SI units, before and after.
    val = json.loads((tmp_path / 'out' / 'validation' / 'validation.json').read_text())
    (after,) = val['misfit'].values()
    (before,) = val['misfit_before'].values()
    assert after['line_pressure']['ratio'] < 1.5
    assert before['line_pressure']['rms'] > 5 * after['line_pressure']['rms']
    assert list((tmp_path / 'out' / 'validation').glob('validate_*.png'))
    # design: on the calibrated plant's own step, not the paper's 0.1 s.
    ctrl = yaml.safe_load((tmp_path / 'controller_cal.yaml').read_text())
    tau = ctrl['/**']['ros__parameters']['model']['tau']
    ac, sp = truth.actuator, truth.spool
    tau_eq14 = ac.S_a * (1 + sp.K_c / sp.K_a) / (ac.mu_a * ac.P_a_bar ** 0.5)
    assert abs(tau / tau_eq14 - 1) < 0.03, (tau, tau_eq14)
