"""``hydropump record`` as a user runs it: the installed command in a subprocess with a short
plan (a staircase with a down-step and a load step; a held-out sine with load and aperture
steps), its bags read back with ``read_recordings`` and held against the plan; and
``--attach`` to nodes started by hand, first with two of them missing."""

import os
from pathlib import Path
import signal
import subprocess
import sys

import numpy as np
import pytest
import yaml

from hydropump_ctrl.ident import read_recordings
from hydropump_ctrl.plans import held_inputs, is_sine, load_plan
from hydropump_sim.params import default_params_path, load_params

from .rosutil import spin_until

pytestmark = pytest.mark.ros

HYDROPUMP = str(Path(sys.executable).with_name('hydropump'))
PLAN = [
    {'name': 'stairs', 'duration': 1.0, 'load_pressure': [[0.5, 9.0e6]],
     'current': {'staircase': {'levels': [40, 60, 50], 'dwell': 0.3}, 'unit': 'percent'}},
    {'name': 'check', 'duration': 0.8, 'held_out': True, 'load_pressure': [[0.4, 1.0e7]],
     'aperture': [[0.2, 0.4]],
     'current': {'offset': 0.5, 'sine': {'amplitude': 0.05, 'frequency': 2.0}}},
]


def hydropump(*args, timeout=120.0):
    """The installed ``hydropump`` in a session of its own; ended through its PID's group
    (it and the nodes it started) if it overruns."""
    proc = subprocess.Popen([HYDROPUMP, *args], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        out, err = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGINT)
        try:
            out, err = proc.communicate(timeout=30)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            out, err = proc.communicate()
        pytest.fail(f'hydropump {" ".join(args)} overran {timeout:g} s:\n{out}\n{err}')
    return proc.returncode, out, err


def _changes(x: np.ndarray) -> list[int]:
    return [int(i) + 1 for i in np.flatnonzero(np.abs(np.diff(x)) > 1e-9)]


def check_bags(out: Path, plan_path: Path, stdout: str) -> None:
    """One bag per experiment, named after it, holding the planned current (levels and
    change instants within a sample) and load pressure (steps within a sample)."""
    params = load_params(default_params_path())
    plan = load_plan(plan_path, params)
    manifest = yaml.safe_load((out / 'record.yaml').read_text())
    assert manifest['held_out'] == plan.held_out
    bags = [Path(b['bag']) for b in manifest['bags']]
    assert [b.name for b in bags] == [e.name for e in plan.experiments]
    assert sorted(p.name for p in out.iterdir() if (p / 'metadata.yaml').is_file()) == \
        sorted(b.name for b in bags)
    for exp, info, rec in zip(plan.experiments, manifest['bags'], read_recordings(bags),
                              strict=True):
        dt = float(np.median(np.diff(rec.t)))
        t = rec.t + rec.t0_ns * 1e-9 - info['start_time_s']
        assert abs(t[0]) < 1e-9 and t[-1] == pytest.approx(exp.duration, abs=1e-9)
        planned = held_inputs(exp, params, dt=dt)
        n = planned.t.size                      # the bag has the end's sample too
        cmd = rec['solenoid_current_cmd'][:n]
        want = planned.current
        if not is_sine(exp.current):
            got_at, want_at = _changes(cmd), _changes(want)
            assert len(got_at) == len(want_at) and all(
                abs(g - w) <= 1 for g, w in zip(got_at, want_at)), (exp.name, got_at, want_at)
            for a, b in zip([0, *want_at], [*want_at, n]):   # each level, as planned
                np.testing.assert_allclose(cmd[a + 1:b - 1], want[a], atol=1e-9)
        else:
            np.testing.assert_allclose(cmd, want, atol=1e-9, err_msg=exp.name)
        # The measured load pressure (absolute, ideal sensors) of the step's sample is the
        # state before it: a step shows within a sample.
        load = rec['load_pressure'][:n] - params.fluid.p_atm
        got_at, want_at = _changes(load), _changes(planned.load_pressure)
        assert len(got_at) == len(want_at) and all(
            0 <= g - w <= 1 for g, w in zip(got_at, want_at)), (exp.name, got_at, want_at)
        np.testing.assert_allclose(load[-1], planned.load_pressure[-1], rtol=1e-9)
        assert f'[{plan.experiments.index(exp) + 1}/{len(plan.experiments)} {exp.name}]' \
            in stdout
    lines = stdout.splitlines()
    assert sum('starts at t = ' in ln for ln in lines) == len(plan.experiments)
    assert sum('s simulated in ' in ln for ln in lines) == len(plan.experiments)
    assert f'held out: {", ".join(plan.held_out)}' in lines


def test_record_runs_a_plan_through_a_graph_of_its_own(tmp_path, ros_domain):
    plan = tmp_path / 'plan.yaml'
    plan.write_text(yaml.safe_dump(PLAN))
    out = tmp_path / 'bags'
    rc, stdout, stderr = hydropump('record', str(plan), '--out', str(out))
    assert rc == 0, stdout + stderr
    assert stderr == ''
    # Its graph in the ROS_DOMAIN_ID it was given (the session's), where one watches it.
    assert f'(ROS domain {ros_domain}' in stdout, stdout
    check_bags(out, plan, stdout)
    assert {p.name for p in (out / 'logs').iterdir()} == {'simulator.log', 'controller.log',
                                                          'recorder.log'}


def test_record_attaches_to_a_running_graph_and_names_what_is_missing(nodes, test_node,
                                                                      tmp_path):
    plan = tmp_path / 'plan.yaml'
    plan.write_text(yaml.safe_dump([dict(PLAN[0], duration=0.7, held_out=True)]))
    nodes.start('simulator', '-p', 'lock_step:=true', '-p', 'start_paused:=true',
                '-p', 'publish_rate:=200.0')
    spin_until(test_node, lambda: any(n == '/simulator/reset' for n, _ in
                                      test_node.get_service_names_and_types()), 30,
               'the simulator')
    # A new participant may miss the first discovery announcements and wait for the next,
    # three seconds later: five seconds to find the simulator.
    rc, stdout, stderr = hydropump('record', str(plan), '--attach', '--wait', '5', '--out',
                                   str(tmp_path / 'none'))
    domain = os.environ['ROS_DOMAIN_ID']
    (line,) = stderr.splitlines()
    assert rc == 2 and line.startswith(
        f'error: no controller, recorder in ROS domain {domain}, the root namespace (looked 5 '
        's; nodes seen there: ') and line.endswith(
        'start them (e.g. hydropump-graph --lock-step --start-paused), or drop --attach to '
        'start a graph of its own'), stderr
    nodes.start('controller', '-p', 'autostart:=true')
    nodes.start('recorder', '-p', 'autostart:=false')
    out = tmp_path / 'bags'
    rc, stdout, stderr = hydropump('record', str(plan), '--attach', '--out', str(out))
    assert rc == 0, stdout + stderr
    assert '[graph] attached: lock-step at 5 ms, 200 Hz' in stdout
    check_bags(out, plan, stdout)
