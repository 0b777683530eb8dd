"""The recorder without DDS: log times by the rule of time, the per-topic watermark, stalls,
idle topics, stops, new bags on a new simulator, and the bag writer's rosbag2 layout."""

import struct

import pytest
import yaml

from hydropump_ctrl.recorder import (
    BagError,
    BagWriter,
    header_stamp,
    qos_profile,
    Recorder,
    RecorderConfig,
    Sequencer,
)
from hydropump_sim.schema import build

from ..recorder_fakes import clock_cdr as _clock
from ..recorder_fakes import float_cdr as _float
from ..recorder_fakes import Graph

MS = 1_000_000


class Clock:
    def __init__(self):
        self.t = 0.0

    def __call__(self):
        return self.t


def _order(records):
    return [(r.log_ns // MS, r.topic) for r in records]


def test_unstamped_messages_wait_for_the_clock_after_them_then_leave_in_order():
    clock = Clock()
    seq = Sequencer(['a', 'b'], clock=clock)
    seq.clock(0, 100)
    seq.message('b', b'b0', source_ns=105, stamp_ns=0)
    seq.message('a', b'a0', source_ns=110)        # unstamped: after the clock of 0 ms
    assert list(seq.ready()) == []                # a's time is not settled yet
    seq.clock(1 * MS, 200)
    seq.message('b', b'b1', source_ns=205, stamp_ns=1 * MS)
    seq.message('a', b'a1', source_ns=210)
    seq.clock(2 * MS, 300)
    assert _order(seq.ready()) == [(0, 'a'), (0, 'b')]   # log time, then the topic order
    assert _order(seq.drain()) == [(1, 'a'), (1, 'b')]


def test_a_topic_that_lags_holds_the_others_back():
    clock = Clock()
    seq = Sequencer(['fast', 'slow'], clock=clock)
    seq.matched('slow')                           # a publisher, nothing delivered yet
    for k in range(5):
        seq.clock(k * MS, 100 * k)
        seq.message('fast', b'f', source_ns=100 * k + 1, stamp_ns=k * MS)
    assert list(seq.ready()) == []                # slow has a publisher: wait for it
    seq.message('slow', b's', source_ns=450, stamp_ns=3 * MS)
    assert _order(seq.ready()) == [(0, 'fast'), (1, 'fast'), (2, 'fast')]


def test_a_silent_topic_stops_holding_back_after_the_idle_timeout():
    clock = Clock()
    seq = Sequencer(['a', 'b'], idle_timeout=1.0, clock=clock)
    seq.matched('b')
    seq.clock(0, 1)
    seq.message('a', b'a', source_ns=2, stamp_ns=0)
    seq.clock(1 * MS, 3)
    seq.message('a', b'a', source_ns=4, stamp_ns=1 * MS)
    assert list(seq.ready()) == []
    clock.t = 1.5                                 # b silent for 1.5 s, a still delivering
    seq.pass_done()
    seq.clock(2 * MS, 5)
    seq.message('a', b'a', source_ns=6, stamp_ns=2 * MS)
    assert _order(seq.ready()) == [(0, 'a'), (1, 'a')]


def test_time_the_recorder_stood_still_is_not_silence():
    clock = Clock()
    seq = Sequencer(['a', 'b'], idle_timeout=1.0, stall=0.05, clock=clock)
    seq.clock(0, 1)
    seq.message('a', b'a', source_ns=2, stamp_ns=0)
    seq.message('b', b'b', source_ns=3, stamp_ns=0)
    seq.pass_done()
    clock.t = 5.0                                 # frozen (SIGSTOP) for 5 s
    seq.pass_done()                               # the first pass after the freeze
    seq.clock(1 * MS, 10)
    seq.message('a', b'a', source_ns=11, stamp_ns=1 * MS)
    # b was not silent for 5 s, the recorder was: b still holds a back...
    assert list(seq.ready()) == []
    seq.message('b', b'b', source_ns=12, stamp_ns=1 * MS)
    # ...until it delivers.
    assert _order(seq.ready()) == [(0, 'a'), (0, 'b')]
    assert seq.buffered == 2


def test_a_late_message_is_written_and_counted():
    clock = Clock()
    seq = Sequencer(['a', 'b'], idle_timeout=0.5, clock=clock)
    seq.clock(0, 1)
    seq.message('a', b'a', source_ns=2, stamp_ns=0)
    seq.clock(2 * MS, 3)
    seq.message('a', b'a', source_ns=4, stamp_ns=2 * MS)
    seq.clock(3 * MS, 5)
    seq.message('a', b'a', source_ns=6, stamp_ns=3 * MS)
    assert _order(seq.ready()) == [(0, 'a'), (2, 'a')]
    seq.message('b', b'b', source_ns=7, stamp_ns=1 * MS)    # a topic coming back late
    assert _order(seq.drain()) == [(1, 'b'), (3, 'a')]
    assert seq.late == 1


def test_wall_time_bags_use_the_receive_time():
    seq = Sequencer(['a'], mode='wall', clock=Clock())
    seq.message('a', b'x', source_ns=5, stamp_ns=7 * MS, receive_ns=123)
    assert [r.log_ns for r in seq.ready()] == [123]


def test_complete_means_every_active_topic_reached_the_stop_time():
    seq = Sequencer(['a', 'b'], clock=Clock())
    seq.clock(0, 1)
    seq.message('a', b'a', source_ns=2, stamp_ns=0)
    seq.message('b', b'b', source_ns=3)
    seq.clock(1 * MS, 10)
    seq.message('a', b'a', source_ns=11, stamp_ns=1 * MS)
    assert not seq.complete(1 * MS)
    seq.message('b', b'b', source_ns=12)          # pending after the clock of 1 ms
    assert seq.complete(1 * MS)


def test_header_stamp_reads_cdr_in_both_byte_orders():
    little = b'\x00\x01\x00\x00' + struct.pack('<iI', 3, 250)
    big = b'\x00\x00\x00\x00' + struct.pack('>iI', 3, 250)
    assert header_stamp(little) == header_stamp(big) == 3_000_000_250


# ---- the bag writer -------------------------------------------------------------------------

def test_the_bag_has_rosbag2s_layout_and_metadata(tmp_path):
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import get_typestore, Stores
    store = get_typestore(Stores.ROS2_JAZZY)
    Float64 = store.types['std_msgs/msg/Float64']
    bag = tmp_path / 'run'
    with BagWriter(bag, compression='zstd', custom_data={'who': 'test'}) as w:
        w.add_topic('/line_flow', 'std_msgs/msg/Float64', [qos_profile()])
        for k in range(5):
            w.write('/line_flow', k * MS, store.serialize_cdr(Float64(data=float(k)),
                                                              Float64.__msgtype__))
    assert sorted(p.name for p in bag.iterdir()) == ['metadata.yaml', 'run_0.mcap']
    text = (bag / 'metadata.yaml').read_text()
    assert not text.endswith('\n')                # yaml-cpp writes no final newline
    info = yaml.safe_load(text)['rosbag2_bagfile_information']
    assert info['ros_distro'] == 'jazzy' and info['compression_format'] == ''
    assert info['duration']['nanoseconds'] == 4 * MS and info['message_count'] == 5
    (topic,) = info['topics_with_message_count']
    assert topic['topic_metadata']['offered_qos_profiles'][0]['deadline'] == {
        'sec': 9223372036, 'nsec': 854775807}
    assert info['custom_data'] == {'who': 'test'}
    with Reader(bag) as r:
        values = [store.deserialize_cdr(raw, c.msgtype).data for c, _, raw in r.messages()]
    assert values == [0.0, 1.0, 2.0, 3.0, 4.0]


def test_a_bag_is_never_overwritten_and_bad_paths_name_the_reason(tmp_path):
    (tmp_path / 'run').mkdir()
    with pytest.raises(BagError, match='exists already'):
        BagWriter(tmp_path / 'run').open()
    (tmp_path / 'file').write_text('')
    with pytest.raises(BagError, match='cannot create the bag'):
        BagWriter(tmp_path / 'file' / 'run').open()
    with pytest.raises(BagError, match="compression = 'lz4'"):
        BagWriter(tmp_path / 'x', compression='lz4')


# ---- the recorder's sessions -----------------------------------------------------------------

def test_a_new_simulator_closes_the_bag_and_opens_the_next(tmp_path):
    logs = []
    cfg = build(RecorderConfig, {'output': str(tmp_path / 'bag'), 'topics': ['/a']})
    rec = Recorder(cfg, ['/a'], Graph(), log=lambda lvl, txt: logs.append(txt))
    rec.start()
    for k, src in ((5, 100), (6, 200)):
        rec.clock(_clock(k * MS), {'source_timestamp': src})
        rec.message('/a', False, _float(), {'source_timestamp': src + 1,
                                            'publication_sequence_number': k})
        rec.advance(1)
    rec.clock(_clock(0), {'source_timestamp': 300})   # time went back
    assert len(rec.closed) == 1 and rec.session.path.name == 'bag_1'
    assert any('went back' in t for t in logs)
    assert rec.request_stop(0.5)
    rec.advance(1)
    assert rec.finish_stop()[0].name == 'bag_1'
    first = yaml.safe_load((tmp_path / 'bag' / 'metadata.yaml').read_text())
    assert first['rosbag2_bagfile_information']['custom_data']['closed_by'].startswith(
        'simulation time went back')


def test_gaps_in_sequence_numbers_are_counted_as_lost(tmp_path):
    cfg = build(RecorderConfig, {'output': str(tmp_path / 'bag'), 'topics': ['/a']})
    rec = Recorder(cfg, ['/a'], Graph(), log=lambda *a: None)
    rec.start()
    rec.clock(_clock(0), {'source_timestamp': 1})
    for n in (1, 2, 5, 6):
        rec.message('/a', False, _float(), {'source_timestamp': 1 + n,
                                            'publication_sequence_number': n})
    rec.request_stop(0.1)
    path, count = rec.finish_stop()
    info = yaml.safe_load((path / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert count == 4
    assert info['custom_data']['messages_lost'] == '2'
    assert info['custom_data']['lost./a'] == '2'


def test_a_stop_time_the_run_never_reaches_ends_the_bag_where_the_run_stopped(
        tmp_path, monkeypatch):
    """A stop at a stop_time the run never reaches (it paused earlier, or ended): once
    /clock has been quiet for SHORT_OF_STOP_TIME the bag ends at the latest /clock, whole,
    nothing counted as lost, and its drain says so; not after the 30 s bound with the
    messages up to the stop_time "estimated" as lost."""
    import time as real

    from hydropump_ctrl.recorder import session
    now = [0.0]

    class Steady:
        @staticmethod
        def monotonic():
            return now[0]
        time_ns = staticmethod(real.time_ns)
    monkeypatch.setattr(session, 'time', Steady)
    cfg = build(RecorderConfig, {'output': str(tmp_path / 'bag'), 'topics': ['/a']})
    rec = Recorder(cfg, ['/a'], Graph(), log=lambda *a: None)
    rec.start()
    for k in range(1, 11):
        rec.clock(_clock(k * MS), {'source_timestamp': 100 * k})
        rec.message('/a', False, _float(), {'source_timestamp': 100 * k + 1,
                                            'publication_sequence_number': k})
        rec.advance(1)
    assert rec.request_stop(30.0, until_ns=1000 * 10 ** 9)     # stop_time = 1000 s
    while rec.stopping and now[0] < 30.0:
        now[0] += 0.05
        rec.advance(1)
    assert now[0] == pytest.approx(session.SHORT_OF_STOP_TIME, abs=0.2)
    path, count = rec.finish_stop()
    told = yaml.safe_load((path / 'metadata.yaml').read_text())[
        'rosbag2_bagfile_information']['custom_data']
    assert count == 10 and told['messages_lost'] == '0'
    assert told['drain'].startswith('complete; the run stopped at t = 0.01 s, before '
                                    'stop_time = 1000 s'), told['drain']


def test_a_topic_that_stops_before_the_bag_ends_is_named_in_it(tmp_path):
    """Two periodic topics: /a goes on to the stop instant, /b stops at 50 ms while /clock
    goes on to 500 ms and its publisher stays in the graph (a publisher that stopped, or one
    whose missed samples DDS had still to repair when the stop took the silent topic as
    ended). The bag names /b with the time of its last message, and the log says so; /a,
    one message short of the stop instant, is not named; nor is a topic whose publisher has
    left the graph."""
    class Leaving(Graph):
        def publishers(self, topic):
            return 0 if topic == '/c' else 1
    logs = []
    cfg = build(RecorderConfig, {'output': str(tmp_path / 'bag'), 'topics': ['/a', '/b', '/c']})
    rec = Recorder(cfg, ['/a', '/b', '/c'], Leaving(('/a', '/b', '/c')),
                   log=lambda lvl, txt: logs.append((lvl, txt)))
    rec.start()
    for k in range(500):
        src = 1000 * (k + 1)
        rec.clock(_clock(k * MS), {'source_timestamp': src})
        for topic in ('/a',) + (('/b', '/c') if k <= 50 else ()):
            if topic == '/a' and k == 499:
                continue                         # one period short of the stop: its edge
            rec.message(topic, False, _float(), {'source_timestamp': src + 1,
                                                 'publication_sequence_number': k + 1})
        rec.advance(1)
    assert rec.request_stop(1.0, until_ns=499 * MS)
    path, _ = rec.finish_stop()
    told = yaml.safe_load((path / 'metadata.yaml').read_text())[
        'rosbag2_bagfile_information']['custom_data']
    assert {k: v for k, v in told.items() if k.startswith('ended.')} == {'ended./b': '0.050000'}
    assert told['messages_lost'] == '0'
    (line,) = [t for lvl, t in logs if 'stopped before the bag ended' in t]
    assert '/b at t = 0.05 s' in line and '/a' not in line and '/c' not in line
    # A reader of the bag is told too, for the topics it reads.
    from hydropump_ctrl.bag.reader import open_bag
    assert [n for n in open_bag(path, ['/a', '/b'])[0].notes if 'stop' in n] == [
        '/b: its recorder saw it stop at t = 0.050000 s, before the bag ended, its publisher '
        'still in the graph (a publisher that stopped, or samples DDS had yet to repair)']
    assert not [n for n in open_bag(path, ['/a'])[0].notes if 'stop' in n]
    assert [n[:3] for n in open_bag(path, None)[0].notes if 'stop' in n] == ['/b:']


# ---- a write that fails ----------------------------------------------------------------------

_FULL_DISK = """
import resource, signal, struct, sys
from hydropump_ctrl.recorder import BagWriteError, BagWriter, qos_profile
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)     # a write past the limit fails with EFBIG
limit = int(sys.argv[2])
resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))
w = BagWriter(sys.argv[1], compression='none', chunk_period=0.01).open()
w.add_topic('/line_flow', 'std_msgs/msg/Float64', [qos_profile()])
try:
    for k in range(10 ** 6):
        w.write('/line_flow', k * 1_000_000, b'\\x00\\x01\\x00\\x00' + struct.pack('<d', k))
    w.close()
except BagWriteError as exc:
    print(exc.messages, exc.reason)
    print(exc)
    try:
        w.write('/line_flow', 0, b'')
    except BagWriteError:
        print('refused')
"""


@pytest.mark.parametrize('limit', [200_000, 200_554, 200_604])
def test_a_failed_write_leaves_a_valid_bag_of_the_whole_chunks(tmp_path, limit):
    """A file-size limit (as a full disk) stops the writer: the MCAP is cut back to its last
    whole chunk and ended there, metadata.yaml counts what it holds, and nothing more is
    taken. The limits put the failure at different bytes of a chunk, so the ending fits
    after the last chunk or needs room made for it."""
    import subprocess
    import sys

    from mcap.reader import make_reader
    from rosbags.rosbag2 import Reader
    bag = tmp_path / 'full'
    proc = subprocess.run([sys.executable, '-c', _FULL_DISK, str(bag), str(limit)],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0 and 'Traceback' not in proc.stderr, proc.stderr
    first, text, refused = proc.stdout.splitlines()
    count, reason = first.split(' ', 1)
    assert reason == 'File too large (EFBIG)' and refused == 'refused'
    assert text.startswith(f'{bag}: cannot write: File too large (EFBIG); the bag is closed '
                           f'with the {count} messages written before (metadata.yaml written)')
    count = int(count)
    assert count > 1000
    path = bag / 'full_0.mcap'
    assert path.stat().st_size <= limit
    # A valid MCAP: the strict reader finds the footer and every message.
    with open(path, 'rb') as f:
        msgs = list(make_reader(f).iter_messages())
    assert len(msgs) == count
    assert [m.log_time for _, _, m in msgs] == [k * 1_000_000 for k in range(count)]
    info = yaml.safe_load((bag / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert info['message_count'] == count
    assert info['topics_with_message_count'][0]['message_count'] == count
    assert info['custom_data']['closed_by'] == 'write error: File too large (EFBIG)'
    with Reader(bag) as r:
        assert sum(1 for _ in r.messages()) == count


def test_a_full_disk_ends_the_recording_with_the_bag_so_far(tmp_path):
    """ENOSPC in the middle of a recording: the bag holds the whole chunks before it, the
    recorder records nothing more and says why (log, diagnostics, start and stop)."""
    import errno

    from mcap.reader import make_reader
    logs = []
    cfg = build(RecorderConfig, {'output': str(tmp_path / 'bag'), 'topics': ['/a'],
                                 'flush_period': 0.1})
    rec = Recorder(cfg, ['/a'], Graph(), log=lambda lvl, txt: logs.append((lvl, txt)))
    rec.start()
    sink = rec.session.writer._fh

    def full(flush=sink.flush):  # the disk fills once 250 messages are in
        if rec.session.writer.count > 250:
            raise OSError(errno.ENOSPC, 'No space left on device')
        flush()
    sink.flush = full
    for k in range(1000):
        rec.clock(_clock(k * MS), {'source_timestamp': 10 * k})
        rec.message('/a', False, _float(), {'source_timestamp': 10 * k + 1,
                                            'publication_sequence_number': k + 1})
        rec.advance(1)
        if rec.failed:
            break
    assert rec.failed is not None and rec.session is None and k < 999
    assert rec.failed.reason == 'No space left on device (ENOSPC)'
    errors = [txt for lvl, txt in logs if lvl == 'error']
    assert len(errors) == 1 and 'recording stopped' in errors[0]
    assert rec.diagnostics()['error'] == 'No space left on device (ENOSPC)'
    with pytest.raises(BagError, match='recording failed'):
        rec.start()
    assert rec.request_stop(0.1) is False and rec.finish_stop() is None
    bag = tmp_path / 'bag'
    with open(bag / 'bag_0.mcap', 'rb') as f:
        n = sum(1 for _ in make_reader(f).iter_messages())
    assert n == rec.failed.messages and n % 100 == 0 and 200 <= n < k  # whole 0.1 s chunks
    info = yaml.safe_load((bag / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert info['message_count'] == n
    assert info['custom_data']['time_base'] == 'simulation'


def test_an_unpublished_topic_is_named_with_the_nearest_known_one():
    from hydropump_ctrl.recorder import SUITE_TYPES, unpublished_note
    known = ['/' + t.lstrip('/') for t in SUITE_TYPES]
    assert unpublished_note('/lien_pressure', known, 5.0) == (
        'no publisher on /lien_pressure after 5 s (did you mean /line_pressure?)')
    ns = ['/pump1/line_flow', '/pump1/load_flow', '/line_flow']
    assert unpublished_note('/pump1/lien_flow', ns, 5.0) == (
        'no publisher on /pump1/lien_flow after 5 s (did you mean /pump1/line_flow?)')
    assert unpublished_note('/camera/image', known, 5.0) == (
        'no publisher on /camera/image after 5 s')


def test_a_bag_name_too_long_is_one_line_not_a_traceback(tmp_path):
    """A 300-character output name: the file system refuses it, and the recorder says so
    (a BagError, which the node turns into its one start-up error line)."""
    from hydropump_ctrl.bag import BagError, open_unique
    with pytest.raises(BagError, match='cannot create the bag: File name too long'):
        open_unique(tmp_path / ('a' * 300))
    assert list(tmp_path.iterdir()) == []


def test_a_topic_whose_publisher_is_discovered_late_gets_its_qos_in_the_bag(tmp_path):
    """Into a running graph the first messages can come before discovery has reported every
    publisher: such a topic's channel waits for its own first message (a channel's QoS
    cannot change once written), and a topic that never sends is still listed at close."""
    known = {'/a'}

    class LateGraph(Graph):
        def offered_qos(self, topic):
            return super().offered_qos(topic) if topic in known else []

    topics = ['/a', '/b', '/c']
    cfg = build(RecorderConfig, {'output': str(tmp_path / 'bag'), 'topics': topics})
    rec = Recorder(cfg, topics, LateGraph(topics), log=lambda *a: None)
    rec.start()
    for k in range(1, 6):
        if k == 3:
            known.add('/b')  # discovery reports /b's publisher, then its messages come
        rec.clock(_clock(k * MS), {'source_timestamp': 100 * k})
        for n, t in enumerate(['/a'] + (['/b'] if k >= 3 else [])):
            rec.message(t, False, _float(), {'source_timestamp': 100 * k + 1 + n,
                                             'publication_sequence_number': k})
        rec.advance(1)
    rec.request_stop(0.1)
    path, _ = rec.finish_stop()
    info = yaml.safe_load((path / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    meta = {e['topic_metadata']['name']: (e['topic_metadata']['offered_qos_profiles'],
                                          e['message_count'])
            for e in info['topics_with_message_count']}
    assert set(meta) == {'/a', '/b', '/c'}
    assert meta['/a'][0][0]['reliability'] == meta['/b'][0][0]['reliability'] == 'reliable'
    assert meta['/b'][1] == 3 and meta['/c'] == ([], 0)


def _periods(topics, clock):
    """A sequencer of ``topics`` fed 300 lock-step periods (a /clock, then each topic's
    message of that instant, in that order) and the /clock of the 301st instant."""
    seq = Sequencer(topics, clock=clock)
    for k in range(300):
        seq.clock(k * MS, 100 * k)
        for j, topic in enumerate(topics):
            seq.message(topic, topic[0].encode(), source_ns=100 * k + 1 + j, stamp_ns=k * MS)
    seq.clock(300 * MS, 30_000)
    return seq


def test_a_topic_one_period_short_of_the_stop_instant_is_waited_for_briefly():
    """A lock-step simulator publishes its pausing instant's measurements just after that
    instant's /clock: a topic whose latest message is one period before the stop instant is
    waited for (its message at the instant may be on its way), for EDGE_GRACE of silence; a
    topic published before each increment has none there and is then done."""
    from hydropump_ctrl.recorder.sequencer import EDGE_GRACE
    clock = Clock()
    seq = _periods(['flow', 'joints'], clock)
    seq.message('flow', b'f', source_ns=30_001, stamp_ns=300 * MS)
    clock.t = 1.0                                   # the stop's request
    assert seq.behind(300 * MS, quiet=1.0, since=1.0) == {'joints': 299 * MS}
    seq.message('joints', b'j', source_ns=30_002, stamp_ns=300 * MS)
    assert seq.behind(300 * MS, quiet=1.0, since=1.0) == {}
    # A topic that has none at the instant is done once silent for the grace.
    clock.t = 0.0
    seq2 = _periods(['current', 'flow'], clock)
    seq2.message('flow', b'f', source_ns=30_002, stamp_ns=300 * MS)
    clock.t = 1.0
    assert seq2.behind(300 * MS, quiet=1.0, since=1.0) == {'current': 299 * MS}
    clock.t = 1.0 + EDGE_GRACE
    assert seq2.behind(300 * MS, quiet=1.0, since=1.0) == {}
    # Two periods short is behind however long it has been quiet (the idle timeout aside).
    assert seq2.behind(301 * MS, quiet=1.0, since=1.0) == {'current': 299 * MS}
