"""Two pumps in one ROS domain, each a simulator, a controller and a recorder in a namespace
of its own, started as a user starts them (the installed executables, a namespace remap):
each controller follows its own simulator's clock, with no restart, and each recorder writes
one bag whose time runs on."""

import pytest

from hydropump_ctrl.ident import read_recording

from .rosutil import spin_until, wait_for_publisher

pytestmark = pytest.mark.ros

PUMPS = ('pump_a', 'pump_b')


def test_two_pumps_in_one_domain(nodes, test_node, tmp_path):
    from rosgraph_msgs.msg import Clock
    started = {}
    for ns in PUMPS:
        remap = ['-r', f'__ns:=/{ns}']
        started[ns] = (
            nodes.start('recorder', *remap, '-p', f'output:={tmp_path / ns}'),
            nodes.start('controller', *remap, '-p', 'autostart:=true'),
        )
    clocks = {ns: [] for ns in PUMPS}
    for ns in PUMPS:
        test_node.create_subscription(Clock, f'/{ns}/clock', clocks[ns].append, 1000)
    # The second pump starts while the first runs: its clock begins at 0 again.
    sims = {PUMPS[0]: nodes.start('simulator', '-r', f'__ns:=/{PUMPS[0]}')}
    wait_for_publisher(test_node, f'/{PUMPS[0]}/clock')
    spin_until(test_node, lambda: clocks[PUMPS[0]] and clocks[PUMPS[0]][-1].clock.sec >= 1,
               60, 'the first pump to run a second')
    sims[PUMPS[1]] = nodes.start('simulator', '-r', f'__ns:=/{PUMPS[1]}')
    spin_until(test_node, lambda: all(c and c[-1].clock.sec >= 3 for c in clocks.values()),
               90, 'both pumps to run three seconds')
    for ns in PUMPS:
        rec, ctrl = started[ns]
        assert rec.stop() == 0 and ctrl.stop() == 0 and sims[ns].stop() == 0
    for ns in PUMPS:
        rec, ctrl = started[ns]
        assert 'another node publishes' not in sims[ns].log()
        # No jump of time reached either controller or recorder.
        assert 'restarting the control law' not in ctrl.log(), ctrl.log()
        assert 'Traceback' not in rec.log() + ctrl.log() + sims[ns].log()
        bags = sorted(p.name for p in tmp_path.iterdir() if p.name.startswith(ns))
        assert bags == [ns], bags                     # one bag: not split by the other pump
        run = read_recording(tmp_path / ns)
        assert run.t[-1] - run.t[0] >= 1.5
        assert (run.t[1:] > run.t[:-1]).all()
        assert 'line_flow' in run and run.t.size > 500
