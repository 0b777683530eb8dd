"""The closed loop split over two hosts: the simulator in one network namespace, the controller
and the recorder in another, joined by a veth pair. Discovery and data go over that link (each
namespace has its own loopback, so nothing can take a localhost shortcut), as between two
machines on one subnet (docs/ros.md, "Several machines").

Discovery range: ``SUBNET`` inside the namespaces, the one place the suite does not use
``LOCALHOST`` - the namespaces' only link is the veth pair, so nothing leaves this machine.
Skipped, with the reason, where network namespaces cannot be made (no root, no ``ip``).
"""

import os
from pathlib import Path
import shutil
import signal
import subprocess
import sys

import numpy as np
import pytest

from .rosutil import executable

pytestmark = pytest.mark.ros

PROBE = """
import sys, time, rclpy
from rclpy.node import Node
from rosgraph_msgs.msg import Clock
from std_srvs.srv import SetBool, Trigger
rclpy.init()
n = Node('two_host_probe')
t = [-1.0]
n.create_subscription(Clock, '/clock', lambda m: t.__setitem__(
    0, m.clock.sec + m.clock.nanosec * 1e-9), 10)
end = time.monotonic() + float(sys.argv[2])

def call(client, req):
    while not client.wait_for_service(timeout_sec=0.1):
        assert time.monotonic() < end, 'no service ' + client.srv_name
    f = client.call_async(req)
    rclpy.spin_until_future_complete(n, f, timeout_sec=10)
    return f.result()

# The recorder (this host) must see every topic before the simulator (the other) runs.
ready = n.create_client(Trigger, 'recorder/ready')
while not call(ready, Trigger.Request()).success:
    assert time.monotonic() < end, 'the recorder never matched its topics'
    time.sleep(0.1)
assert call(n.create_client(SetBool, 'simulator/pause'), SetBool.Request(data=False)).success
while t[0] < float(sys.argv[1]) and time.monotonic() < end:
    rclpy.spin_once(n, timeout_sec=0.05)
print(t[0])
sys.exit(0 if t[0] >= float(sys.argv[1]) else 1)
"""


def _ip(*args, check=True):
    return subprocess.run(['ip', *args], capture_output=True, text=True, check=check)


@pytest.fixture
def two_hosts():
    """Two namespaces ``A`` (10.77.<k>.1) and ``B`` (.2) over a veth pair; removed after."""
    if shutil.which('ip') is None:
        pytest.skip('no ip command: network namespaces cannot be made here')
    k = os.getpid() % 200 + 20
    a, b = f'hpA{os.getpid()}', f'hpB{os.getpid()}'
    made = _ip('netns', 'add', a, check=False)
    if made.returncode:
        pytest.skip(f'network namespaces cannot be made here: {made.stderr.strip()}')
    try:
        _ip('netns', 'add', b)
        _ip('link', 'add', f'va{k}', 'type', 'veth', 'peer', 'name', f'vb{k}')
        for ns, dev, addr in ((a, f'va{k}', f'10.77.{k}.1/24'), (b, f'vb{k}', f'10.77.{k}.2/24')):
            _ip('link', 'set', dev, 'netns', ns)
            _ip('-n', ns, 'addr', 'add', addr, 'dev', dev)
            _ip('-n', ns, 'link', 'set', dev, 'up', 'multicast', 'on')
            _ip('-n', ns, 'link', 'set', 'lo', 'up')
            # Discovery is multicast: route it onto the link.
            _ip('-n', ns, 'route', 'add', '224.0.0.0/4', 'dev', dev)
    except subprocess.CalledProcessError as exc:
        for ns in (a, b):
            _ip('netns', 'del', ns, check=False)
        pytest.skip(f'network namespaces cannot be linked here: {exc.stderr.strip()}')
    yield a, b
    for ns in (a, b):
        _ip('netns', 'del', ns, check=False)


def test_closed_loop_over_two_hosts(two_hosts, ros_domain, tmp_path):
    from hydropump_ctrl.ident import read_recording
    from hydropump_sim.params import default_params_path, load_params
    a, b = two_hosts
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE='SUBNET',
               ROS_DOMAIN_ID=str(ros_domain))
    bag = tmp_path / 'two_hosts'
    procs = []

    def start(ns, cmd, name):
        log = open(tmp_path / f'{name}.log', 'w')  # noqa: SIM115 - closed with the process
        p = subprocess.Popen(['ip', 'netns', 'exec', ns, *cmd], env=env, stdout=log,
                             stderr=subprocess.STDOUT)
        procs.append((p, log))
        return p

    try:
        # Host A: the plant. Host B: the controller (EMC, flow mode, 50 %: its defaults) and
        # the recorder. Lock-step, so the loop runs only while both hosts talk.
        start(a, [executable('simulator'), '--ros-args', '-p', 'lock_step:=true', '-p',
                  'start_paused:=true', '-p', 'wait_subscribers:=1'], 'simulator')
        start(b, [executable('controller'), '--ros-args', '-p', 'autostart:=true'], 'controller')
        start(b, [executable('recorder'), '--ros-args', '-p', f'output:={bag}', '-p',
                  'topics:=[line_flow, solenoid_current, solenoid_current_cmd, '
                  'line_pressure, load_pressure, pump_flow, load_flow, actuator_pressure, '
                  'joint_states]'], 'recorder')
        # On host B: the recorder ready, the simulator on host A un-paused (a service call
        # over the link), then simulation time up to 2 s (/clock over the link).
        probe = subprocess.run(['ip', 'netns', 'exec', b, sys.executable, '-c', PROBE, '2.0',
                                '90'], env=env, capture_output=True, text=True, timeout=120)
        logs = {n: (tmp_path / f'{n}.log').read_text()[-1500:]
                for n in ('simulator', 'controller', 'recorder')}
        assert probe.returncode == 0, (probe.stdout, probe.stderr, logs)
    finally:
        for p, _ in procs:
            if p.poll() is None:
                p.send_signal(signal.SIGINT)
        for p, log in procs:
            try:
                p.wait(timeout=20)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()
            log.close()
    assert all(p.returncode == 0 for p, _ in procs), [p.returncode for p, _ in procs]
    rec = read_recording(next(Path(bag).parent.glob('two_hosts*')))
    params = load_params(default_params_path())
    # The loop closed across the link: commands recorded in simulation time, every 5 ms, and
    # the flow held at the controller's 50 % reference.
    assert rec.t[-1] >= 1.5
    t = rec.t
    cmd = rec['solenoid_current_cmd']
    assert np.isfinite(cmd).sum() >= 0.9 * (t[-1] - t[0]) / 0.005
    late = t > t[-1] - 0.5
    assert abs(np.nanmean(rec['line_flow'][late]) / params.Q_max - 0.5) < 0.01
