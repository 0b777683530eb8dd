"""A lock-step graph started as `ros2 launch ... lock_step:=true` starts it (no start_paused,
the controller and the simulator at once): the first step waits until the controller is
matched, so no instant waits out lock_step_timeout for a command that went to nobody, and
no event (a lock-step timeout, a safe current) is published."""

import pytest

from .rosutil import spin_until

pytestmark = pytest.mark.ros


@pytest.mark.parametrize('attempt', range(3))
def test_a_lock_step_start_never_waits_out_the_timeout(attempt, nodes, test_node):
    from diagnostic_msgs.msg import DiagnosticArray
    from rosgraph_msgs.msg import Clock
    clocks, events = [], []
    test_node.create_subscription(Clock, '/clock', clocks.append, 100)
    test_node.create_subscription(DiagnosticArray, 'events', events.append, 100)
    ctrl = nodes.start('controller', '-p', 'autostart:=true', '-p',
                       'watchdog.simulation_time:=true')
    sim = nodes.start('simulator', '-p', 'lock_step:=true', '-p', 'lock_step_timeout:=5.0')
    spin_until(test_node, lambda: clocks and clocks[-1].clock.sec >= 1, 60,
               'one second of lock-step simulation')
    assert sim.stop() == 0 and ctrl.stop() == 0
    log = sim.log()
    assert 'no command within lock_step_timeout' not in log, log
    assert 'commanding the safe current' not in ctrl.log()
    assert events == []     # neither a lock-step timeout nor a safe current to tell a bag
