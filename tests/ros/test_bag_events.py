"""A bag tells of what makes its record unfit: the controller's safe-current engagements and
the simulator's lock-step timeouts reach the bag (the ``events`` topic, always recorded) and
its ``custom_data``, and the check run before every fit refuses the bag with one line. The
truth: a simulator frozen for longer than the controller's ``watchdog.safe_timeout`` (an
engagement at the simulation time it was frozen at; as many in all as the controller logged);
a lock-step run with a controller that never answers (every control instant up to
``pause_at`` times out)."""

import os
import signal
import time

import numpy as np
import pytest
import yaml

from .rosutil import call, spin_until, wait_for_publisher, wait_for_subscriber
from .test_recorder import read_mcap

pytestmark = pytest.mark.ros


def _custom_data(bag):
    info = yaml.safe_load((bag / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    return info['custom_data']


def _refused(bag, *words):
    """The check before every fit (``hydropump fit``: one ``error:`` line) refuses the bag."""
    from hydropump_ctrl.ident import read_recordings
    from hydropump_ctrl.ident.errors import PlausibilityError
    from hydropump_sim.params import default_params_path, load_params
    with pytest.raises(PlausibilityError) as err:
        read_recordings([bag], params=load_params(default_params_path()), check=())
    (line,) = [ln for ln in err.value.lines if 'its recorder reports' in ln]
    for w in words:
        assert w in line, (w, line)
    return line


def _recording_in_simulation_time(test_node):
    """Wait until the recorder's bag is in simulation time: it has the simulator's /clock
    (on a loaded machine one reader may be matched seconds after another)."""
    from diagnostic_msgs.msg import DiagnosticArray
    bases = []
    sub = test_node.create_subscription(DiagnosticArray, '/diagnostics', lambda m: bases.extend(
        {v.key: v.value for v in st.values}.get('time_base') for st in m.status
        if st.name == 'recorder'), 10)
    spin_until(test_node, lambda: 'sim' in bases, 30, 'the recorder to take /clock')
    test_node.destroy_subscription(sub)


def _stop_recorder(test_node):
    """``~/stop``; the bag it closed (a bag that began in wall time, before /clock was
    discovered, is followed by one in simulation time: the last is the one)."""
    from pathlib import Path

    from std_srvs.srv import Trigger
    res = call(test_node, test_node.create_client(Trigger, 'recorder/stop'), Trigger.Request(),
               timeout=30)
    assert res.success, res.message
    return Path(res.message.rsplit(' (', 1)[0])


def test_a_safe_current_engagement_is_in_the_bag_and_refused_by_the_fit(
        nodes, test_node, tmp_path, capsys):
    from rosgraph_msgs.msg import Clock
    from std_msgs.msg import Float64
    bag = tmp_path / 'safe'
    # A topics list without events: the events are recorded all the same.
    rec = nodes.start('recorder', '-p', f'output:={bag}',
                      '-p', 'topics:=[solenoid_current_cmd, solenoid_current, line_flow]')
    # The simulator's own command watchdog is kept out of it (the controller's alone).
    sim = nodes.start('simulator', '-p', 'command_timeout:=600.0')
    ctrl = nodes.start('controller', '-p', 'autostart:=true',
                       '-p', 'watchdog.hold_timeout:=0.5', '-p', 'watchdog.safe_timeout:=1.0')
    clocks, cmds = [], []
    test_node.create_subscription(Clock, '/clock', lambda m: clocks.append(
        m.clock.sec * 10**9 + m.clock.nanosec), 1000)
    test_node.create_subscription(Float64, 'solenoid_current_cmd', cmds.append, 1000)
    spin_until(test_node, lambda: len(cmds) > 200 and len(clocks) > 200, 60,
               'the controller to command, and /clock here')
    wait_for_subscriber(test_node, 'events')
    _recording_in_simulation_time(test_node)
    os.kill(sim.pid, signal.SIGSTOP)
    settled = time.monotonic() + 0.2   # the clocks already sent come in
    spin_until(test_node, lambda: time.monotonic() > settled, 5, 'the last clocks')
    frozen_at = clocks[-1]
    try:
        time.sleep(2.0)                    # > watchdog.safe_timeout: the safe current
    finally:
        os.kill(sim.pid, signal.SIGCONT)
    n = len(clocks)
    spin_until(test_node, lambda: len(clocks) > n + 500, 30, 'the simulation to go on')
    bag = _stop_recorder(test_node)
    # The truth: the engagements the controller logged (ours; a loaded machine may stall
    # the simulator long enough for another).
    logged = ctrl.log().count('commanding the safe current')
    assert logged >= 1, ctrl.log()
    cd = _custom_data(bag)
    assert cd['events.safe_current'] == str(logged), cd
    assert cd['events.lock_step_timeout'] == '0', cd
    events = read_mcap(bag)['/events']
    assert len(events) == logged
    assert round(float(cd['events.safe_current.first']) * 1e9) == min(t for t, _ in events)
    # Stamped where the simulation froze: at a simulation time the simulator published in
    # the last control periods before it stopped (the controller stamps its last update's
    # instant, which may be a step or a few before the last clock this node received on a
    # loaded machine), not at a wall time nor after the resume.
    near = [e for e in events if e[0] in set(clocks) and frozen_at - 20_000_000 <= e[0]
            <= frozen_at]
    assert len(near) == 1, ([t for t, _ in events], frozen_at)
    (t, msg), = near
    (status,) = msg.status
    kv = {v.key: v.value for v in status.values}
    assert status.name == 'safe_current' and kv['source'] == 'controller'
    assert float(kv['command_A']) == pytest.approx(0.3)     # limits.safe_current
    line = _refused(bag, f'{logged} safe-current engagement')
    # As a user meets it: one error line, exit code 2, no result.
    from hydropump_ctrl.cli import main
    code = main(['fit', str(bag), '--no-report', '--no-progress'])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and err == [f'error: {line}'], err
    assert rec.stop() == 0 and sim.stop() == 0 and ctrl.stop() == 0


def test_lock_step_timeouts_are_in_the_bag_and_refused_by_the_fit(nodes, test_node, tmp_path):
    from std_msgs.msg import Float64
    from std_srvs.srv import SetBool, Trigger
    bag = tmp_path / 'timeouts'
    spin_until(test_node, lambda: test_node.count_publishers('line_flow') == 0, 30,
               'the graph to forget earlier simulators')
    rec = nodes.start('recorder', '-p', f'output:={bag}')
    sim = nodes.start('simulator', '-p', 'lock_step:=true', '-p', 'lock_step_timeout:=0.05',
                      '-p', 'start_paused:=true', '-p', 'pause_at:=0.1',
                      '-p', 'wait_subscribers:=1')
    # A controller that never answers: matched (the simulator waits for one), silent.
    test_node.create_publisher(Float64, 'solenoid_current_cmd', 10)
    wait_for_publisher(test_node, 'line_flow')
    ready = test_node.create_client(Trigger, 'recorder/ready')
    spin_until(test_node, lambda: call(test_node, ready, Trigger.Request()).message ==
               'waiting for a publisher on /controller/state', 30, 'the recorder to match')
    wait_for_subscriber(test_node, 'events')
    from rosgraph_msgs.msg import Clock
    clocks = []
    test_node.create_subscription(Clock, '/clock', clocks.append, 1000)
    call(test_node, test_node.create_client(SetBool, 'simulator/pause'),
         SetBool.Request(data=False))
    spin_until(test_node, lambda: clocks and clocks[-1].clock.nanosec >= 100_000_000, 60,
               'the pause at 0.1 s')
    assert _stop_recorder(test_node) == bag
    rec.stop()
    sim.stop()
    # Every control instant 0, 5, ..., 95 ms timed out; the one of 0.1 s is after the pause.
    want = np.arange(0, 100, 5) * 1_000_000
    cd = _custom_data(bag)
    assert cd['events.lock_step_timeout'] == str(want.size), cd
    assert cd['events.lock_step_timeout.first'] == '0.000000'
    assert cd['events.safe_current'] == '0'
    events = read_mcap(bag)['/events']
    assert [t for t, _ in events] == list(want)
    for _, msg in events:
        (status,) = msg.status
        kv = {v.key: v.value for v in status.values}
        assert status.name == 'lock_step_timeout' and kv['source'] == 'simulator'
        assert 'lock_step_timeout = 0.05 s' in status.message
    _refused(bag, '20 lock-step timeouts (the first at 0 s)')


def test_the_simulators_command_watchdog_is_a_safe_current_event(nodes, test_node, tmp_path):
    """Commands that stop in a paced run: after command_timeout (0.2 s, steady clock; the run
    is paced at real time) the simulator applies the safe current, once, and the bag says
    when in simulation time."""
    from rosgraph_msgs.msg import Clock
    from std_msgs.msg import Float64
    bag = tmp_path / 'watchdog'
    spin_until(test_node, lambda: test_node.count_publishers('line_flow') == 0, 30,
               'the graph to forget earlier simulators')
    rec = nodes.start('recorder', '-p', f'output:={bag}')
    sim = nodes.start('simulator', '-p', 'command_timeout:=0.2')
    clocks, seen = [], []      # simulation time, and the steady time it reached this node
    test_node.create_subscription(Clock, '/clock', lambda m: (clocks.append(
        m.clock.sec + m.clock.nanosec * 1e-9), seen.append(time.monotonic())), 1000)
    cmd = test_node.create_publisher(Float64, 'solenoid_current_cmd', 10)
    wait_for_subscriber(test_node, 'solenoid_current_cmd')
    wait_for_subscriber(test_node, 'events')
    spin_until(test_node, lambda: len(clocks) > 500, 30, 'the run')
    _recording_in_simulation_time(test_node)
    for _ in range(20):                              # 0.1 s of commands, then none
        cmd.publish(Float64(data=0.5))
        end = time.monotonic() + 0.005
        spin_until(test_node, lambda end=end: time.monotonic() > end, 5, 'the next command')
    sent = time.monotonic()
    last = clocks[-1]
    spin_until(test_node, lambda: 'applying the safe current' in sim.log(), 10,
               'the watchdog')
    n = len(clocks)
    spin_until(test_node, lambda: len(clocks) > n + 300, 30, 'the run to go on')
    bag = _stop_recorder(test_node)
    assert rec.stop() == 0 and sim.stop() == 0
    cd = _custom_data(bag)
    assert cd['events.safe_current'] == '1', cd
    first = float(cd['events.safe_current.first'])
    # The timeout is steady-clock time (the contract); what it is in simulation time depends
    # on how fast the run went meanwhile, which a busy machine slows: the event lies at or
    # after the simulation time this node had seen 0.2 s of steady time after the last
    # command (its view lags the simulator's, never leads it), and before what it had seen
    # half a second later.
    def seen_at(t):
        return max(c for c, w in zip(clocks, seen) if w <= t)
    assert last < first, (last, first)
    assert seen_at(sent + 0.2) - 0.01 <= first <= seen_at(sent + 0.7) + 0.05, \
        (last, seen_at(sent + 0.2), first, seen_at(sent + 0.7))
    # The commands stopped long before the bag's end, their publisher still in the graph:
    # the bag names the topic, with the time of its last message (before the event).
    assert last - 0.05 <= float(cd['ended./solenoid_current_cmd']) < first, (last, first, cd)
    (event,) = read_mcap(bag)['/events']
    (status,) = event[1].status
    assert {v.key: v.value for v in status.values}['source'] == 'simulator'
    assert 'applying the safe current' in status.message
    _refused(bag, '1 safe-current engagement')
