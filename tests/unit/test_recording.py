"""Reading rosbag2 bags (MCAP and sqlite3) into recordings of named signals.

Bags are written as the project's recorder writes them (``rosbags``, version 9), as
``ros2 bag record`` writes them (an MCAP with zstd chunks from ``mcap-ros2-support`` and a
Jazzy ``metadata.yaml``), cut short, killed with SIGKILL, and corrupted.
"""

import json
import os
from pathlib import Path
import signal
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from hydropump_ctrl.bag import typestore
from hydropump_ctrl.ident import (
    BagError,
    list_topics,
    match_topic,
    read_recording,
    read_recordings,
    Recording,
    recording_to_bag,
    SIGNALS,
    write_bag,
)
from hydropump_sim.errors import HydropumpError

F64 = 'std_msgs/msg/Float64'
PRESSURE = 'sensor_msgs/msg/FluidPressure'
T0 = 1_000.0          # s: bags start at a non-zero simulation time
HASH = 'RIHS01_705ba9c3d1a09df43737eb67095534de36fd426c0587779bda2bc51fe790182a'


def _signals(n=4000, dt=1e-3, seed=0):
    rng = np.random.default_rng(seed)
    t = T0 + np.arange(n) * dt
    cur = 0.46 + 0.08 * (np.arange(n) // 500 % 2) + 1e-3 * rng.standard_normal(n)
    flow = 6e-4 + 1e-5 * rng.standard_normal(n)
    return t, cur, flow


def _contract_bag(path, storage='mcap', ns='', n=4000):
    """The recorder's topics: Float64 current and flows, FluidPressure with header stamps."""
    t, cur, flow = _signals(n)
    p = f'/{ns}' if ns else ''
    return write_bag(path, {
        f'{p}/solenoid_current': (F64, t, cur),
        f'{p}/solenoid_current_cmd': (F64, t, np.round(cur, 2)),
        f'{p}/line_flow': (F64, t, flow),
        f'{p}/pump_flow': (F64, t, flow * 1.01),
        f'{p}/load_flow': (F64, t, flow * 0.99),
        f'{p}/line_pressure': (PRESSURE, t, 1.5e7 + flow),
        f'{p}/load_pressure': (PRESSURE, t, 1.2e7 + flow),
    }, storage=storage), (t, cur, flow)


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
def test_recorder_bag_is_read_exactly(tmp_path, storage):
    bag, (t, cur, flow) = _contract_bag(tmp_path / 'bag', storage, ns='pump')
    rec = read_recording(bag)
    assert rec.roles == {'current': 'solenoid_current', 'flow': 'line_flow'}
    names = ['solenoid_current', 'solenoid_current_cmd', 'line_flow', 'pump_flow', 'load_flow',
             'line_pressure', 'load_pressure']
    assert rec.topics == {n: f'/pump/{n}' for n in names}
    assert rec.time_source == {n: 'header' if 'pressure' in n else 'log' for n in names}
    assert rec.dt == pytest.approx(1e-3, rel=1e-9)
    assert rec.t0_ns == int(round(T0 * 1e9))
    np.testing.assert_allclose(rec.t, t - T0, atol=1e-9)
    np.testing.assert_array_equal(rec.current, cur)
    np.testing.assert_array_equal(rec.flow, flow)
    assert not rec.truncated and not rec.notes
    assert rec.labels['line_flow'] == 'line flow q_l'
    # Every contract signal of the bag is decoded once, in SI (pressures as published).
    np.testing.assert_array_equal(rec['pump_flow'], flow * 1.01)
    np.testing.assert_array_equal(rec['line_pressure'], 1.5e7 + flow)
    np.testing.assert_array_equal(rec['solenoid_current_cmd'], np.round(cur, 2))
    assert rec.units['line_pressure'] == 'Pa (absolute)' and rec.units['load_flow'] == 'm^3/s'
    # The command topic is selectable; 'solenoid_current' never matched it by suffix.
    cmd = read_recording(bag, current_topic='solenoid_current_cmd', flow_topic='pump_flow')
    np.testing.assert_array_equal(cmd.current, np.round(cur, 2))
    np.testing.assert_array_equal(cmd.flow, flow * 1.01)


def test_header_stamps_are_used_where_present(tmp_path):
    # Log times 3 ms late with jitter; the FluidPressure header carries the sample time.
    t, cur, flow = _signals(2000)
    write_bag(tmp_path / 'bag', {'/solenoid_current': (F64, t, cur),
                                 '/line_pressure': (PRESSURE, t, 1.5e7 + 1e5 * flow)},
              log_offset_ns=3_000_000)
    rec = read_recording(tmp_path / 'bag', flow_topic='line_pressure')
    assert rec.time_source == {'solenoid_current': 'log', 'line_pressure': 'header'}
    # The current keeps its (late) log times, the pressure its stamps: the first common
    # instant is the first current message, which pairs with the fourth pressure sample.
    n = rec.t.size
    assert n == 2000 - 3
    np.testing.assert_array_equal(rec.current, cur[:n])
    np.testing.assert_array_equal(rec.flow, (1.5e7 + 1e5 * flow)[3:])


def test_header_stamps_from_simulation_time_zero(tmp_path):
    # The simulator stamps its first step 0 ns; the recorder logs at receive time.
    t = np.arange(1000) * 1e-3
    write_bag(tmp_path / 'bag', {'/solenoid_current': (F64, t, 0.5 + 0 * t),
                                 '/line_pressure': (PRESSURE, t, 1.5e7 + t)},
              log_offset_ns=2_000_000)
    rec = read_recording(tmp_path / 'bag', flow_topic='line_pressure')
    assert rec.time_source['line_pressure'] == 'header'
    np.testing.assert_array_equal(rec.flow, (1.5e7 + t)[2:])


def test_independent_mcap_like_ros2_bag_record(tmp_path):
    # zstd-chunked MCAP from mcap-ros2-support and the metadata.yaml Jazzy writes.
    from mcap_ros2.writer import Writer
    bag = tmp_path / 'rosbag2_2026_11_22-05_00_00'
    bag.mkdir()
    t, cur, flow = _signals(3000)
    with open(bag / 'rosbag2_2026_11_22-05_00_00_0.mcap', 'wb') as f:
        w = Writer(f, chunk_size=64 * 1024)
        schema = w.register_msgdef(F64, 'float64 data')
        for tk, c, q in zip(t, cur, flow):
            ns = int(round(tk * 1e9))
            w.write_message('/solenoid_current', schema, {'data': float(c)}, log_time=ns)
            w.write_message('/line_flow', schema, {'data': float(q)}, log_time=ns)
        w.finish()
    qos = textwrap.indent(textwrap.dedent("""\
        - history: keep_last
          depth: 10
          reliability: reliable
          durability: volatile
          deadline: {sec: 9223372036, nsec: 854775807}
          lifespan: {sec: 9223372036, nsec: 854775807}
          liveliness: automatic
          liveliness_lease_duration: {sec: 9223372036, nsec: 854775807}
          avoid_ros_namespace_conventions: false"""), ' ' * 10)
    topics = ''.join(f"""
    - topic_metadata:
        name: {name}
        type: std_msgs/msg/Float64
        serialization_format: cdr
        offered_qos_profiles:
{qos}
        type_description_hash: {HASH}
      message_count: 3000""" for name in ('/solenoid_current', '/line_flow'))
    (bag / 'metadata.yaml').write_text(f"""rosbag2_bagfile_information:
  version: 9
  storage_identifier: mcap
  duration:
    nanoseconds: 2999000000
  starting_time:
    nanoseconds_since_epoch: {int(T0 * 1e9)}
  message_count: 6000
  topics_with_message_count:{topics}
  compression_format: ""
  compression_mode: ""
  relative_file_paths:
    - rosbag2_2026_11_22-05_00_00_0.mcap
  files:
    - path: rosbag2_2026_11_22-05_00_00_0.mcap
      starting_time:
        nanoseconds_since_epoch: {int(T0 * 1e9)}
      duration:
        nanoseconds: 2999000000
      message_count: 6000
  custom_data: ~
  ros_distro: jazzy
""")
    rec = read_recording(bag)
    assert rec.t.size == 3000 and not rec.truncated
    np.testing.assert_array_equal(rec.current, cur)
    np.testing.assert_array_equal(rec.flow, flow)
    # The MCAP file alone reads the same.
    alone = read_recording(bag / 'rosbag2_2026_11_22-05_00_00_0.mcap')
    np.testing.assert_array_equal(alone.flow, flow)


def test_topic_matching_exact_or_unique_suffix():
    topics = {'/a/line_flow': F64, '/b/line_flow': F64, '/solenoid_current_cmd': F64,
              '/solenoid_current': F64, '/clock': 'rosgraph_msgs/msg/Clock'}
    assert match_topic('/a/line_flow', topics) == '/a/line_flow'
    assert match_topic('a/line_flow', topics) == '/a/line_flow'
    assert match_topic('solenoid_current', topics) == '/solenoid_current'
    with pytest.raises(BagError, match=r'ambiguous.*/a/line_flow, /b/line_flow'):
        match_topic('line_flow', topics)
    with pytest.raises(BagError, match=r"no topic 'pump_flow'; it has: /a/line_flow"):
        match_topic('pump_flow', topics)
    assert match_topic('flow', {'/line_flow': F64, '/flow': F64}) == '/flow'
    with pytest.raises(BagError):
        match_topic('flow', {'/line_flow': F64})      # suffixes start at a '/'


def test_missing_topic_lists_what_the_bag_has(tmp_path):
    bag, _ = _contract_bag(tmp_path / 'bag')
    with pytest.raises(BagError) as err:
        read_recording(bag, flow_topic='q_flow')
    msg = str(err.value)
    assert "no topic 'q_flow'" in msg and '/line_flow (std_msgs/msg/Float64)' in msg
    assert '/line_pressure (sensor_msgs/msg/FluidPressure)' in msg and '\n' not in msg
    assert list_topics(bag)['/load_pressure'] == PRESSURE


def test_nan_values_are_reported(tmp_path):
    t, cur, flow = _signals(1000)
    flow[[400, 401, 900]] = np.nan
    write_bag(tmp_path / 'bag', {'/solenoid_current': (F64, t, cur),
                                 '/line_flow': (F64, t, flow)})
    with pytest.raises(BagError, match=r'line_flow has 3 NaN .*t = 0\.4 s'):
        read_recording(tmp_path / 'bag')


def test_receive_time_jitter_keeps_current_and_flow_paired(tmp_path):
    # ros2 bag record without simulation time: both topics logged at receive time, the
    # current up to 0.4 ms after the flow of its own step.
    rng = np.random.default_rng(3)
    n = 2000
    k = np.arange(n)
    cur = 0.46 + 0.08 * (k // 250 % 2)
    flow = 1e-4 * k
    t_flow = T0 + k * 1e-3 + rng.uniform(0, 1e-4, n)
    t_cur = t_flow + rng.uniform(0, 4e-4, n)
    write_bag(tmp_path / 'bag', {'/solenoid_current': (F64, t_cur, cur),
                                 '/line_flow': (F64, t_flow, flow)})
    rec = read_recording(tmp_path / 'bag')
    m = rec.t.size
    np.testing.assert_array_equal(rec.current[1:], cur[1:m])
    assert np.max(np.abs(rec.flow - 1e-4 * (rec.t / 1e-3 + 0.0))) < 2e-5


def test_command_published_on_change_is_held(tmp_path):
    # A current command published only when it changes: the grid follows the flow.
    t, _, flow = _signals(3000)
    t_cmd = T0 + np.array([0.0, 0.7, 1.9, 2.4])
    cmd = np.array([0.46, 0.54, 0.50, 0.58])
    write_bag(tmp_path / 'bag', {'/solenoid_current_cmd': (F64, t_cmd, cmd),
                                 '/line_flow': (F64, t, flow)})
    rec = read_recording(tmp_path / 'bag', current_topic='solenoid_current_cmd')
    assert rec.dt == pytest.approx(1e-3, rel=1e-9) and rec.t.size == 3000
    np.testing.assert_array_equal(rec.flow, flow)
    expect = cmd[np.searchsorted(t_cmd - T0, rec.t + 1e-12, side='right') - 1]
    np.testing.assert_array_equal(rec.current, expect)
    assert any('held since' in n for n in rec.notes)


def test_compressed_bag(tmp_path):
    from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin, Writer

    ts = typestore()
    t, cur, flow = _signals(1000)
    w = Writer(tmp_path / 'z', version=9, storage_plugin=StoragePlugin.MCAP)
    w.set_compression(CompressionMode.MESSAGE, CompressionFormat.ZSTD)
    with w:
        conns = [w.add_connection(n, F64, typestore=ts) for n in ('/solenoid_current',
                                                                   '/line_flow')]
        cls = ts.types[F64]
        for tk, c, q in zip(t, cur, flow):
            for conn, val in zip(conns, (c, q)):
                w.write(conn, int(round(tk * 1e9)), ts.serialize_cdr(cls(data=val), F64))
    rec = read_recording(tmp_path / 'z')
    np.testing.assert_array_equal(rec.current, cur)
    np.testing.assert_array_equal(rec.flow, flow)


def test_resampling_holds_the_current_and_interpolates_the_flow(tmp_path):
    # Current at 1 kHz, flow at 500 Hz stamped half a millisecond later, unsorted, one
    # duplicate stamp.
    t, cur, _ = _signals(2000)
    tf = T0 + 0.0005 + np.arange(1000) * 2e-3
    flow = 1e-4 * np.sin(tf - T0)
    order = np.random.default_rng(1).permutation(1000)
    write_bag(tmp_path / 'bag', {'/solenoid_current': (F64, t, cur),
                                 '/line_flow': (F64, np.r_[tf[order], tf[5]],
                                                np.r_[flow[order], flow[5]])})
    rec = read_recording(tmp_path / 'bag')
    assert rec.dt == pytest.approx(2e-3, rel=1e-9)
    grid = rec.t + rec.t0_ns * 1e-9
    np.testing.assert_allclose(rec.flow, 1e-4 * np.sin(grid - T0), atol=2e-10)
    # Held current: the last value published up to half a period after each grid time.
    k = np.searchsorted(t, grid + 1e-3 + 1e-9, side='right') - 1
    np.testing.assert_array_equal(rec.current, cur[k])
    assert any('repeated time stamps' in n for n in rec.notes)


def _long_bag(path, seconds=30.0):
    """A bag of several rosbags chunks (about 12 s of two 1 kHz topics per chunk)."""
    t = T0 + np.arange(int(seconds * 1000)) * 1e-3
    cur = 0.46 + 0.08 * ((t - T0) // 0.5 % 2)
    flow = 6e-4 + 1e-6 * (t - T0)
    write_bag(path, {'/solenoid_current': (F64, t, cur), '/line_flow': (F64, t, flow)})
    return t, cur, flow


def test_mcap_cut_short_is_read_up_to_its_last_whole_chunk(tmp_path):
    t, cur, flow = _long_bag(tmp_path / 'bag')
    mcap = next((tmp_path / 'bag').glob('*.mcap'))
    data = mcap.read_bytes()
    for with_metadata in (True, False):
        cut = tmp_path / f'cut{with_metadata}'
        cut.mkdir()
        (cut / mcap.name).write_bytes(data[:int(0.8 * len(data))])
        if with_metadata:
            (cut / 'metadata.yaml').write_text((tmp_path / 'bag' / 'metadata.yaml').read_text())
        rec = read_recording(cut)
        assert rec.truncated and 'no footer' in rec.truncation
        assert 5.0 < rec.duration < 29.0
        np.testing.assert_array_equal(rec.current, cur[:rec.t.size])
        np.testing.assert_array_equal(rec.flow, flow[:rec.t.size])
        assert with_metadata or any('metadata.yaml' in n for n in rec.notes)
    # Cut inside the first chunk: nothing readable, a clear error.
    bad = tmp_path / 'tiny.mcap'
    bad.write_bytes(data[:5000])
    with pytest.raises(BagError, match='truncated'):
        read_recording(bad)


RECORDER = """
import sys, time
import numpy as np
from hydropump_ctrl.bag import typestore
from hydropump_sim.errors import HydropumpError
from rosbags.rosbag2 import StoragePlugin, Writer
ts = typestore()
F = ts.types['std_msgs/msg/Float64']
w = Writer(sys.argv[1], version=9, storage_plugin=StoragePlugin.MCAP)
w.open()
c_cur = w.add_connection('/solenoid_current', 'std_msgs/msg/Float64', typestore=ts)
c_flow = w.add_connection('/line_flow', 'std_msgs/msg/Float64', typestore=ts)
for k in range(40000):
    ns = 1_000_000_000_000 + k * 1_000_000
    w.write(c_cur, ns, ts.serialize_cdr(F(data=0.46 + 0.08 * (k // 500 % 2)), F.__msgtype__))
    w.write(c_flow, ns, ts.serialize_cdr(F(data=6e-4 + 1e-9 * k), F.__msgtype__))
print('recorded', flush=True)
time.sleep(60)
"""


def test_recorder_killed_with_sigkill(tmp_path):
    bag = tmp_path / 'killed'
    proc = subprocess.Popen([sys.executable, '-c', RECORDER, str(bag)],
                            stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().strip() == 'recorded'
    finally:
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(timeout=10)
    assert not (bag / 'metadata.yaml').exists()
    rec = read_recording(bag)
    assert rec.truncated and 'no footer' in rec.truncation
    assert rec.t.size > 10000
    k = np.arange(rec.t.size)
    np.testing.assert_allclose(rec.flow, 6e-4 + 1e-9 * k, rtol=0, atol=1e-15)


def test_broken_inputs_give_one_line_errors(tmp_path):
    cases = {}
    (tmp_path / 'notes.txt').write_text('hello')
    cases['notes.txt'] = 'is not a rosbag2 bag'
    (tmp_path / 'empty').mkdir()
    cases['empty'] = 'is not a rosbag2 bag'
    (tmp_path / 'junk.mcap').write_bytes(os.urandom(4096))
    cases['junk.mcap'] = 'not an MCAP file'
    (tmp_path / 'junk.db3').write_bytes(os.urandom(4096))
    cases['junk.db3'] = 'not an SQLite database'
    cases['missing'] = 'no such file or directory'
    bag, _ = _contract_bag(tmp_path / 'sq', 'sqlite3')
    db = next(Path(bag).glob('*.db3'))
    db.write_bytes(db.read_bytes()[:len(db.read_bytes()) // 3])
    cases['sq'] = 'cannot read'
    for name, expect in cases.items():
        with pytest.raises(BagError) as err:
            read_recording(tmp_path / name)
        msg = str(err.value)
        assert expect in msg and '\n' not in msg, (name, msg)
        assert isinstance(err.value, HydropumpError) and err.value.lines == [msg]


def test_unreadable_metadata_falls_back_to_the_mcap(tmp_path):
    bag, (_, cur, _) = _contract_bag(tmp_path / 'bag')
    (bag / 'metadata.yaml').write_text('rosbag2_bagfile_information: [unclosed\n')
    rec = read_recording(bag)
    np.testing.assert_array_equal(rec.current, cur)
    assert not rec.truncated and any('metadata.yaml' in n for n in rec.notes)


def test_saved_recording_round_trip(tmp_path):
    t, cur, flow = _signals(500)
    rec = Recording(t - T0, {'solenoid_current': cur, 'line_flow': flow}, name='r1',
                    source='x', notes=['a note'], truncated=True, truncation='cut')
    path = rec.save(tmp_path / 'r1.npz')
    back = read_recording(path)
    np.testing.assert_array_equal(back.current, cur)
    np.testing.assert_array_equal(back.t, t - T0)
    assert back.notes == ['a note'] and back.truncated and back.truncation == 'cut'
    assert back.units == {'t': 's', 'solenoid_current': 'A', 'line_flow': 'm^3/s'}
    half = back.decimate(2)
    assert half.dt == pytest.approx(2e-3) and half.t.size == 250
    (tmp_path / 'bad.npz').write_bytes(b'not a zip')
    with pytest.raises(BagError, match='not a saved recording'):
        read_recording(tmp_path / 'bad.npz')


def test_corrupted_mcap_never_raises_anything_but_a_bag_error(tmp_path):
    bag, _ = _contract_bag(tmp_path / 'bag', n=1500)
    data = next(bag.glob('*.mcap')).read_bytes()
    rng = np.random.default_rng(11)
    outcomes = set()
    for i in range(25):
        broken = bytearray(data)
        at = int(rng.integers(0, len(data) - 64))
        broken[at:at + int(rng.integers(1, 64))] = rng.bytes(64)[:len(broken[at:at + 64])]
        d = tmp_path / f'c{i}'
        d.mkdir()
        (d / 'bag.mcap').write_bytes(bytes(broken[:len(data)]))
        try:
            rec = read_recording(d)
            outcomes.add('read')
            assert rec.t.size >= 2
        except BagError as exc:
            outcomes.add('error')
            assert '\n' not in str(exc)
    assert outcomes == {'read', 'error'}    # both kinds of outcome occur, nothing else


# ---- named signals ----------------------------------------------------------------------------

JOINTS = 'sensor_msgs/msg/JointState'
STATE_KEYS = ('reference', 'estimate', 'disturbance', 'command', 'command_desired')


def _loop_bag(path, n=2000):
    """The closed-loop recorder's topics in namespace ``pump``: the simulator's at 1 kHz, the
    controller's command and state at 200 Hz from its first update at 5 ms (the state's
    disturbance undefined), and a ``joint_states`` of another namespace."""
    rng = np.random.default_rng(5)
    t = T0 + np.arange(n) * 1e-3
    tc = t[5::5]
    sig = {'line_flow': 6e-4 + 1e-5 * rng.standard_normal(n),
           'spool_position': 1e-4 * rng.standard_normal(n),
           'actuator_position': 0.01 + 1e-3 * rng.standard_normal(n),
           'line_pressure': 1.5e7 + 1e4 * rng.standard_normal(n),
           'load_pressure': 1.2e7 + 1e4 * rng.standard_normal(n),
           'solenoid_current_cmd': 0.46 + 0.08 * (np.arange(tc.size) // 40 % 2)}
    sig['solenoid_current'] = sig['solenoid_current_cmd'][np.clip(np.arange(n) // 5 - 1, 0,
                                                                  None)]
    state = {k: rng.standard_normal(tc.size) for k in STATE_KEYS}
    state['disturbance'][:] = np.nan
    write_bag(path, {
        '/pump/solenoid_current': (F64, t, sig['solenoid_current']),
        '/pump/solenoid_current_cmd': (F64, tc, sig['solenoid_current_cmd']),
        '/pump/line_flow': (F64, t, sig['line_flow']),
        '/pump/line_pressure': (PRESSURE, t, sig['line_pressure']),
        '/pump/load_pressure': (PRESSURE, t, sig['load_pressure']),
        '/pump/joint_states': (JOINTS, t, {'spool': sig['spool_position'],
                                           'swash_plate_actuator': sig['actuator_position']}),
        '/pump/controller/state': (JOINTS, tc, state),
        '/other/joint_states': (JOINTS, t, {'spool': 0 * t}),
    })
    return t, tc, sig, state


def test_a_bag_is_decoded_once_into_every_contract_signal(tmp_path):
    t, tc, sig, state = _loop_bag(tmp_path / 'bag')
    rec = read_recording(tmp_path / 'bag')
    assert set(rec.signals) == {*sig, *(f'controller_{k}' for k in STATE_KEYS)}
    assert not rec.notes
    # Sampled signals stamped on the grid are taken as they are, positions by entry name,
    # the namespace of the flow first (the other joint_states is not taken).
    for name in ('line_flow', 'spool_position', 'actuator_position', 'line_pressure',
                 'load_pressure', 'solenoid_current'):
        np.testing.assert_array_equal(rec[name], sig[name], err_msg=name)
    assert rec.topics['spool_position'] == '/pump/joint_states'
    assert rec.topics['controller_reference'] == '/pump/controller/state'
    # Held signals: the last value stamped up to half a period after each grid time, NaN
    # before the first message.
    grid = rec.t + rec.t0_ns * 1e-9
    k = np.searchsorted(tc, grid + 5e-4, side='right') - 1
    for name, v in (('solenoid_current_cmd', sig['solenoid_current_cmd']),
                    ('controller_command', state['command'])):
        expect = np.where(k >= 0, v[np.clip(k, 0, None)], np.nan)
        np.testing.assert_array_equal(rec[name], expect, err_msg=name)
    assert np.isnan(rec['solenoid_current_cmd'][:5]).all()
    assert np.isnan(rec['controller_disturbance']).all()     # kept, not an error
    # Units and labels are the contract's; pressures stay absolute, as published.
    for name in rec.signals:
        assert rec.units[name] == SIGNALS[name].unit and rec.labels[name] == SIGNALS[name].label
    assert rec.units['line_pressure'] == 'Pa (absolute)'
    assert rec.units['controller_command'] == 'A' and rec.units['t'] == 's'
    assert rec.time_source['spool_position'] == 'header'


def test_signals_can_be_chosen_and_a_chosen_one_must_be_there(tmp_path):
    _loop_bag(tmp_path / 'loop')
    only = read_recording(tmp_path / 'loop', signals=['load_pressure'])
    assert set(only.signals) == {'solenoid_current', 'line_flow', 'load_pressure'}
    assert set(read_recording(tmp_path / 'loop', signals=None).signals) == {
        'solenoid_current', 'line_flow'}
    bag, _ = _contract_bag(tmp_path / 'plain')
    with pytest.raises(BagError, match="no topic 'joint_states'"):
        read_recording(bag, signals=['spool_position'])
    with pytest.raises(BagError, match="unknown signal 'x_a'"):
        read_recording(bag, signals=['x_a'])


def test_an_undecodable_signal_is_left_out_with_a_note(tmp_path):
    from hydropump_ctrl.bag import BagWriter, qos_profile
    t, cur, flow = _signals(1000)
    ts = typestore()
    F = ts.types[F64]
    # joint_states of the right type whose payloads are not CDR (a corrupt publisher).
    with BagWriter(tmp_path / 'bag', compression='none') as w:
        for topic, msgtype in (('/solenoid_current', F64), ('/line_flow', F64),
                               ('/joint_states', 'sensor_msgs/msg/JointState')):
            w.add_topic(topic, msgtype, [qos_profile()])
        for k, tk in enumerate(t):
            ns = int(round(tk * 1e9))
            w.write('/solenoid_current', ns, ts.serialize_cdr(F(data=cur[k]), F64))
            w.write('/line_flow', ns, ts.serialize_cdr(F(data=flow[k]), F64))
            w.write('/joint_states', ns, b'\x00\x01')
    rec = read_recording(tmp_path / 'bag')
    assert 'spool_position' not in rec and 'actuator_position' not in rec
    assert any('spool_position, actuator_position left out' in n and 'cannot decode' in n
               for n in rec.notes)
    with pytest.raises(BagError, match='cannot decode /joint_states'):
        read_recording(tmp_path / 'bag', signals=['spool_position'])


def test_a_contract_topic_of_another_type_is_refused(tmp_path):
    # Read as numbers all the same, a Float64 joint_states would pass for positions.
    t, cur, flow = _signals(1000)
    write_bag(tmp_path / 'bag', {'/solenoid_current': (F64, t, cur),
                                 '/line_flow': (F64, t, flow),
                                 '/joint_states': (F64, t, flow)})
    for signals in ('all', ['spool_position']):
        with pytest.raises(BagError, match='is not a sensor_msgs/msg/JointState: wrong '
                           'message type for spool_position'):
            read_recording(tmp_path / 'bag', signals=signals)
    assert set(read_recording(tmp_path / 'bag', signals=None).signals) == {
        'solenoid_current', 'line_flow'}


def test_every_signal_survives_npz_and_bag_round_trips(tmp_path):
    _loop_bag(tmp_path / 'bag')
    rec = read_recording(tmp_path / 'bag')
    back = Recording.load(rec.save(tmp_path / 'rec.npz'))
    again = read_recording(recording_to_bag(rec, tmp_path / 'again', namespace='pump',
                                            start_s=T0))
    for other in (back, again):
        assert set(other.signals) == set(rec.signals) and other.roles == rec.roles
        for name, v in rec.signals.items():
            np.testing.assert_array_equal(other[name], v, err_msg=name)
        assert other.units == rec.units and other.topics == rec.topics
    assert back.t0_ns == rec.t0_ns and back.time_source == rec.time_source


def test_roles_pick_the_signals_that_act_as_current_and_flow(tmp_path):
    _loop_bag(tmp_path / 'bag')
    rec = read_recording(tmp_path / 'bag')
    cmd = rec.with_roles(current='solenoid_current_cmd')
    assert cmd.roles == {'current': 'solenoid_current_cmd', 'flow': 'line_flow'}
    assert cmd.current is cmd['solenoid_current_cmd'] and rec.with_roles() is rec
    with pytest.raises(BagError, match="no signal 'q' to act as the flow"):
        rec.with_roles(flow='q')
    # A saved recording takes the roles it is read with, where it has the signals.
    path = rec.save(tmp_path / 'r.npz')
    assert read_recording(path, current_topic='/pump/solenoid_current_cmd').roles == cmd.roles
    # Filters are kept per signal; 'current' and 'flow' name the roles.
    low = cmd.lowpass(50.0, signals=('current', 'load_pressure'))
    assert low.filters['solenoid_current_cmd'].startswith('butterworth order 2, 50 Hz')
    assert low.filters['load_pressure'] and low.filters['line_flow'] is None
    with pytest.raises(BagError, match="unknown signal 'torque'"):
        rec.lowpass(50.0, signals=('torque',))


def test_read_recordings_refuses_a_truncated_bag_unless_allowed(tmp_path):
    _long_bag(tmp_path / 'bag')
    data = (next((tmp_path / 'bag').glob('*.mcap'))).read_bytes()
    (tmp_path / 'cut').mkdir()
    (tmp_path / 'cut' / 'bag.mcap').write_bytes(data[:int(0.8 * len(data))])
    good, _ = _contract_bag(tmp_path / 'good')
    with pytest.raises(BagError) as err:
        read_recordings([good, tmp_path / 'cut'])
    assert 'cut: the bag is truncated' in str(err.value) and '\n' not in str(err.value)
    recs = read_recordings([good, tmp_path / 'cut'], allow_truncated=True, signals=None)
    assert [r.truncated for r in recs] == [False, True]
    assert [r.name for r in read_recordings(good)] == ['good']


def test_a_saved_current_and_flow_recording_of_earlier_versions_loads(tmp_path):
    t, cur, flow = _signals(300)
    meta = {'name': 'old', 'source': 'b', 'topics': {'current': '/solenoid_current_cmd',
                                                     'flow': '/p/line_flow'},
            'labels': {'current': 'I', 'flow': 'q'}, 'time_source': {'current': 'log',
                                                                     'flow': 'header'},
            'truncated': False, 'truncation': '', 'notes': [], 't0_ns': 5,
            'filters': {'current': None, 'flow': 'x'}, 'units': {'t': 's'}}
    np.savez(tmp_path / 'old.npz', t=t - T0, current=cur, flow=flow,
             meta=np.array(json.dumps(meta)))
    rec = read_recording(tmp_path / 'old.npz')
    assert rec.roles == {'current': 'solenoid_current_cmd', 'flow': 'line_flow'}
    np.testing.assert_array_equal(rec.current, cur)
    np.testing.assert_array_equal(rec.flow, flow)
    assert rec.topics == {'solenoid_current_cmd': '/solenoid_current_cmd',
                          'line_flow': '/p/line_flow'}
    assert rec.filters == {'solenoid_current_cmd': None, 'line_flow': 'x'}
    assert rec.units['solenoid_current_cmd'] == 'A' and rec.t0_ns == 5
