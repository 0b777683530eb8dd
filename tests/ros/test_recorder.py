"""The recorder over real DDS: real rosbag2 MCAP bags, read back with an independent reader,
repeatable lock-step runs, clean SIGINT and a bounded SIGKILL loss."""

import filecmp
import signal
import time

import numpy as np
import pytest

from .rosutil import call, LockStepDriver, spin_until, wait_for_publisher, wait_for_subscriber

pytestmark = pytest.mark.ros

SUITE = ('solenoid_current', 'pump_flow', 'line_flow', 'load_flow', 'actuator_pressure',
         'line_pressure', 'load_pressure', 'joint_states')


def read_mcap(bag_dir):
    """Messages of a bag with Foxglove's mcap reader and its ROS 2 decoder (streaming, so a
    file without summary, as a hard kill leaves it, reads too)."""
    from mcap.exceptions import McapError
    from mcap.reader import NonSeekingReader
    from mcap_ros2.decoder import DecoderFactory
    (path,) = bag_dir.glob('*.mcap')
    out = {}
    with open(path, 'rb') as f:
        reader = NonSeekingReader(f, decoder_factories=[DecoderFactory()])
        try:
            for _schema, channel, message, decoded in reader.iter_decoded_messages(
                    log_time_order=False):
                out.setdefault(channel.topic, []).append((message.log_time, decoded))
        except (McapError, EOFError, ValueError):
            pass  # a truncated tail ends the stream
    return out


def _run(nodes, test_node, bag, until=0.4, schedule=None, period=0.005):
    """Simulator in lock-step, recorder, and a stand-in controller from t = 0 to ``until``."""
    topics = '[' + ', '.join(('solenoid_current_cmd',) + SUITE) + ']'
    rec = nodes.start('recorder', '-p', 'use_sim_time:=true', '-p', f'output:={bag}',
                      '-p', f'topics:={topics}')
    sim = nodes.start('simulator', '-p', 'lock_step:=true', '-p', 'lock_step_timeout:=30.0',
                      '-p', 'initial_current:=0.46', '-p', 'start_paused:=true')
    driver = LockStepDriver(test_node, schedule or (lambda t: 0.46 if t < 0.1 else 0.54),
                            period)
    wait_for_subscriber(test_node, 'solenoid_current_cmd')
    wait_for_publisher(test_node, 'line_flow')
    # The recorder has matched a publisher on every topic before the first step.
    from std_srvs.srv import Trigger
    ready = test_node.create_client(Trigger, 'recorder/ready')
    spin_until(test_node, lambda: call(test_node, ready, Trigger.Request()).success, 30,
               'the recorder to be ready')
    wait_for_subscriber(test_node, '/clock')
    from std_srvs.srv import SetBool
    call(test_node, test_node.create_client(SetBool, 'simulator/pause'),
         SetBool.Request(data=False))
    driver.kick()
    spin_until(test_node, lambda: driver.t >= until, 120, f'simulation time {until} s')
    driver.active = False  # the simulator now waits for a command that does not come
    return sim, rec, driver


def _stop_recorder(test_node):
    from std_srvs.srv import Trigger
    client = test_node.create_client(Trigger, 'recorder/stop')
    res = call(test_node, client, Trigger.Request(), timeout=30)
    assert res.success, res.message
    return res


def test_bag_is_complete_and_reads_with_an_independent_decoder(nodes, test_node, tmp_path):
    from rosbags.rosbag2 import Reader
    bag = tmp_path / 'run'
    _run(nodes, test_node, bag, until=0.5)
    _stop_recorder(test_node)
    assert (bag / 'metadata.yaml').is_file()
    meta = (bag / 'metadata.yaml').read_text()
    assert 'version: 9' in meta and 'storage_identifier: mcap' in meta
    msgs = read_mcap(bag)
    for topic in SUITE:
        times = np.array([t for t, _ in msgs[f'/{topic}']]) * 1e-9
        # every step from the start of the run, none missing, none twice (1 ms apart)
        assert times[0] <= 0.005, topic
        # The applied current of the last instant waits for its command, which never comes.
        assert times[-1] >= 0.5 - (0.005 if topic == 'solenoid_current' else 0.0), topic
        assert np.allclose(np.diff(times), 1e-3, atol=1e-9), topic
    cmd = np.array([t for t, _ in msgs['/solenoid_current_cmd']]) * 1e-9
    assert np.allclose(np.diff(cmd), 0.005, atol=1e-9)  # one command per control period
    # Stamped messages are logged at their header stamp.
    for t, m in msgs['/line_pressure'][:50]:
        assert t == m.header.stamp.sec * 10**9 + m.header.stamp.nanosec
    # The command of the instant t and the applied current published at t agree.
    applied = dict(msgs['/solenoid_current'])
    for t, m in msgs['/solenoid_current_cmd']:
        assert applied[t].data == pytest.approx(m.data)
    # rosbags reads it as a rosbag2 bag with the same counts.
    with Reader(bag) as r:
        counts = {c.topic: c.msgcount for c in r.connections}
    assert all(counts[t] == len(v) for t, v in msgs.items())


def test_lock_step_runs_are_bit_identical(nodes, test_node, tmp_path):
    bags = []
    for run in ('a', 'b'):
        bag = tmp_path / run / 'bag'
        sim, rec, _ = _run(nodes, test_node, bag, until=0.3)
        _stop_recorder(test_node)
        sim.stop()
        rec.stop()
        bags.append(bag)
    a, b = bags
    assert filecmp.cmp(a / 'bag.mcap', b / 'bag.mcap', shallow=False)
    assert (a / 'metadata.yaml').read_text() == (b / 'metadata.yaml').read_text()


def test_sigint_closes_the_bag(nodes, test_node, tmp_path):
    bag = tmp_path / 'sigint'
    _, rec, _ = _run(nodes, test_node, bag, until=0.2)
    assert rec.stop(signal.SIGINT) == 0
    assert (bag / 'metadata.yaml').is_file()
    msgs = read_mcap(bag)
    assert len(msgs['/line_flow']) >= 200


def test_sigkill_loses_a_bounded_tail(nodes, test_node, tmp_path):
    """After SIGKILL the MCAP has no summary and there is no metadata.yaml; what was flushed
    reads, and the loss is at most flush_period + reorder_window (0.35 s) of sim time."""
    bag = tmp_path / 'sigkill'
    _, rec, driver = _run(nodes, test_node, bag, until=1.2)
    t_kill = driver.t
    time.sleep(0.5)  # the recorder catches up with what was published
    rec.stop(signal.SIGKILL)
    assert not (bag / 'metadata.yaml').exists()
    msgs = read_mcap(bag)
    last = max(t for t, _ in msgs['/line_flow']) * 1e-9
    assert t_kill - last <= 0.35 + 0.01
    times = np.array([t for t, _ in msgs['/line_flow']]) * 1e-9
    assert np.allclose(np.diff(times), 1e-3, atol=1e-9)  # what is there is whole
