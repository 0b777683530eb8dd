"""A stop drains: what was published up to the stop and is still on its way reaches the bag,
also from a recorder that lags (frozen with SIGSTOP, as a loaded machine freezes it); what
cannot is counted as lost, never ``messages_lost: 0`` with data missing. The truth is what
the simulator publishes: one message per topic per step of 1 ms, from 0 to its ``pause_at``.
The first tests run the recorder logic without DDS, on streams built here."""

import os
import signal
import time
import types

import numpy as np
import pytest
import yaml

from ..recorder_fakes import clock_cdr as _clock
from ..recorder_fakes import float_cdr as _float
from ..recorder_fakes import Graph
from .rosutil import call, spin_until, wait_for_publisher
from .test_recorder import read_mcap

SUITE = ('solenoid_current', 'pump_flow', 'line_flow', 'load_flow', 'actuator_pressure',
         'line_pressure', 'load_pressure', 'joint_states')
MS = 1_000_000


def _info(path):
    return yaml.safe_load((path / 'metadata.yaml').read_text())['rosbag2_bagfile_information']


# ---- the drain without DDS ----------------------------------------------------------------

def _recorder(tmp_path, topics, **cfg):
    from hydropump_ctrl.recorder import message_definition, Recorder, RecorderConfig
    from hydropump_sim.schema import build
    message_definition('std_msgs/msg/Float64')   # loaded now, not as a stall of a pass
    base = build(RecorderConfig, {'output': str(tmp_path / 'bag'), 'topics': topics})
    conf = types.SimpleNamespace(**{**vars(base), **cfg}) if cfg else base
    return Recorder(conf, list(topics), Graph(topics), log=lambda *a: None)


def _step(rec, k, src, topics, seq):
    """Step ``k`` of a simulator: its /clock, then one unstamped message per topic."""
    rec.clock(_clock(k * MS), {'source_timestamp': src, 'publication_sequence_number': k + 1})
    for i, t in enumerate(topics):
        rec.message(t, False, _float(k), {'source_timestamp': src + 1 + i,
                                          'publication_sequence_number': seq})


def test_a_drain_cut_at_its_bound_counts_the_queued_and_the_missing_tail(tmp_path):
    """Steps 0..99 published, at 1 ms of simulation time each (source times 10 us apart);
    the stop comes after step 99. The recorder has taken steps 0..59 when the bound passes;
    steps 60..79 are still queued (taken unwritten), 80..99 never arrived. Every one of the
    100 messages per topic is in the bag or counted lost; the bag ends at the stop."""
    topics = ['/a', '/b']
    rec = _recorder(tmp_path, topics, drain_timeout=0.0)
    rec.start()
    for k in range(60):
        _step(rec, k, 10_000 * k, topics, k + 1)
        rec.advance(1)
    wall = 10_000 * 99 + 5_000                   # after step 99 was published
    assert rec.request_stop(0.0, wall_ns=wall, reason='SIGINT')
    rec.advance(1)                               # the bound has passed
    assert rec.needs_count
    for k in range(60, 80):                      # clocks first, as the node takes them
        rec.clock(_clock(k * MS), {'source_timestamp': 10_000 * k,
                                   'publication_sequence_number': k + 1})
    rec.settle_stop()
    for k in range(60, 80):
        for i, t in enumerate(topics):
            rec.unwritten(t, False, _float(k), {'source_timestamp': 10_000 * k + 1 + i,
                                                'publication_sequence_number': k + 1})
    rec.counted()
    assert not rec.stopping
    path, count = rec.closed[-1]
    cd = _info(path)['custom_data']
    assert cd['closed_by'] == 'SIGINT'
    assert cd['drain'].startswith('cut after 0 s')
    written = read_mcap(path)
    # The known stop instant is the latest /clock the recorder had when it gave up (79 ms):
    # 80 steps are in the bag or counted (the 20 queued); the tail past 79 ms is unknown.
    for t in topics:
        assert len(written[t]) + int(cd[f'lost.{t}']) == 80, cd
        times = [x for x, _ in written[t]]
        assert len(set(times)) == len(times)     # none written at another step's time
    assert int(cd['messages_lost']) == 40 and count == 120


def test_a_cut_drain_estimates_a_tail_that_never_came_from_the_topics_rate(tmp_path):
    """The /clock stream is complete up to the stop (99 ms), the data of /a only up to 59 ms
    and of /b up to 79 ms: the missing 40 and 20 are counted from their 1 ms period."""
    topics = ['/a', '/b']
    rec = _recorder(tmp_path, topics, drain_timeout=0.0)
    rec.start()
    for k in range(100):
        src = 10_000 * k
        rec.clock(_clock(k * MS), {'source_timestamp': src,
                                   'publication_sequence_number': k + 1})
        for i, (t, last) in enumerate((('/a', 59), ('/b', 79))):
            if k <= last:
                rec.message(t, False, _float(k), {'source_timestamp': src + 1 + i,
                                                  'publication_sequence_number': k + 1})
        rec.advance(1)
    rec.clock(_clock(100 * MS), {'source_timestamp': 1_000_000,
                                 'publication_sequence_number': 101})
    assert rec.request_stop(0.0, wall_ns=10_000 * 99 + 5_000)
    rec.advance(1)
    assert rec.needs_count
    rec.settle_stop()
    rec.counted()
    path, _ = rec.closed[-1]
    cd = _info(path)['custom_data']
    written = read_mcap(path)
    assert len(written['/a']) == 60 and len(written['/b']) == 80
    assert cd['lost./a'] == '40' and cd['lost./b'] == '20'
    assert 'estimated' in cd['drain'] and '/a, /b' in cd['drain']


def test_messages_sent_while_clocks_were_lost_are_counted_not_misplaced(tmp_path):
    """/clock samples 3 to 6 lost on the way (their sequence numbers skipped): an unstamped
    message sent between the /clock of step 2 and that of step 7 has no known time (step 2's
    own cannot be told from the next ones'). They are counted as lost, never written at the
    time of step 2."""
    topics = ['/a']
    rec = _recorder(tmp_path, topics)
    rec.start()
    for k in range(10):
        src = 10_000 * k
        if not 3 <= k <= 6:
            rec.clock(_clock(k * MS), {'source_timestamp': src,
                                       'publication_sequence_number': k + 1})
        rec.message('/a', False, _float(k), {'source_timestamp': src + 1,
                                              'publication_sequence_number': k + 1})
        rec.advance(1)
    rec.request_stop(0.5, wall_ns=10_000 * 9 + 5)
    path, count = rec.finish_stop()
    cd = _info(path)['custom_data']
    times = [t // MS for t, _ in read_mcap(path)['/a']]
    assert times == [0, 1, 7, 8, 9]
    assert cd['lost./a'] == '5' and cd['messages_lost'] == '5'


def test_a_stop_leaves_out_what_was_sent_after_it_and_writes_nothing_twice(tmp_path):
    """A paced run goes on after the stop: the messages of the steps after it are not in the
    bag and are not lost; one that waits for its /clock at the close is not written at the
    time of the stop's step."""
    topics = ['/a']
    rec = _recorder(tmp_path, topics)
    rec.start()
    for k in range(5):
        _step(rec, k, 10_000 * k, topics, k + 1)
        rec.advance(1)
    assert rec.request_stop(2.0, wall_ns=10_000 * 4 + 5_000)   # during step 4
    for k in range(5, 8):                                       # the run goes on
        _step(rec, k, 10_000 * k, topics, k + 1)
        rec.advance(1)
    assert not rec.stopping                                      # drained at once
    path, _ = rec.closed[-1]
    cd = _info(path)['custom_data']
    assert [t // MS for t, _ in read_mcap(path)['/a']] == [0, 1, 2, 3, 4]
    assert cd['messages_lost'] == '0' and cd['drain'] == 'complete'
    assert cd['closed_by'] == 'stop'


# ---- over DDS -----------------------------------------------------------------------------

class ClockLog:
    """The /clock samples the test receives, with their source timestamps (the
    simulator's wall clock when it published them)."""

    def __init__(self, node):
        from rosgraph_msgs.msg import Clock
        self.samples = []
        node.create_subscription(Clock, '/clock', lambda m, info: self.samples.append(
            (info['source_timestamp'], m.clock.sec * 10**9 + m.clock.nanosec)), 1000)

    @property
    def latest(self) -> float:
        return self.samples[-1][1] * 1e-9

    def at(self, wall_ns: int) -> float:
        """Simulation time [s] of the latest /clock published at or before ``wall_ns``."""
        return max(t for src, t in self.samples if src <= wall_ns) * 1e-9


def _spin_for(test_node, seconds):
    end = time.monotonic() + seconds
    spin_until(test_node, lambda: time.monotonic() > end, seconds + 5, f'{seconds} s')


def _paced_run(nodes, test_node, tmp_path, until, topics=SUITE):
    """A simulator paced at real time that pauses at ``until`` s, the recorder started as
    ``ros2 run`` starts it on ``topics``; returns (recorder, simulator, clock log, bag path)
    once the run is going."""
    from std_srvs.srv import SetBool, Trigger
    spin_until(test_node, lambda: test_node.count_publishers('line_flow') == 0, 30,
               'the graph to forget earlier simulators')
    bag = tmp_path / 'bag'
    rec = nodes.start('recorder', '-p', f'output:={bag}',
                      '-p', 'topics:=[' + ', '.join(topics) + ']')
    # No controller: the simulator's command watchdog has nothing to trip on.
    sim = nodes.start('simulator', '-p', 'start_paused:=true', '-p', f'pause_at:={until}',
                      '-p', 'wait_subscribers:=1')
    clocks = ClockLog(test_node)
    wait_for_publisher(test_node, 'line_flow')
    ready = test_node.create_client(Trigger, 'recorder/ready')
    spin_until(test_node, lambda: call(test_node, ready, Trigger.Request()).success, 30,
               'the recorder to be ready')
    call(test_node, test_node.create_client(SetBool, 'simulator/pause'),
         SetBool.Request(data=False))
    return rec, sim, clocks, bag


@pytest.mark.ros
@pytest.mark.parametrize('freeze_at, how', [(2.2, 'SIGINT'), (0.5, 'SIGINT'), (0.5, 'stop')])
def test_a_lagging_recorder_stopped_keeps_what_was_published_or_counts_it(
        nodes, test_node, tmp_path, freeze_at, how):
    """The recorder is frozen from ``freeze_at`` s of a 3 s run until the simulator has
    paused at its end, then resumed and stopped at once (SIGINT, or ``~/stop``), with its
    backlog untaken. Frozen for 0.8 s, the publishers still hold what it missed (a second
    per topic): the bag holds the whole run. Frozen for 2.5 s, they no longer do: what is
    not in the bag is counted as lost, exactly, in the bag and on /diagnostics."""
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
    from std_srvs.srv import Trigger
    statuses = []
    test_node.create_subscription(DiagnosticArray, '/diagnostics', lambda m: statuses.extend(
        st for st in m.status if st.name == 'recorder'), 10)
    rec, sim, clocks, bag = _paced_run(nodes, test_node, tmp_path, 3.0)
    stop = test_node.create_client(Trigger, 'recorder/stop')
    spin_until(test_node, stop.service_is_ready, 30, "the recorder's ~/stop")
    spin_until(test_node, lambda: clocks.samples and clocks.latest >= freeze_at, 60,
               f'simulation time {freeze_at} s')
    os.kill(rec.pid, signal.SIGSTOP)
    try:
        spin_until(test_node, lambda: clocks.latest >= 3.0 - 1e-9, 60, 'the end of the run')
        time.sleep(0.2)
    finally:
        os.kill(rec.pid, signal.SIGCONT)
    t0 = time.monotonic()
    if how == 'SIGINT':
        assert rec.stop(signal.SIGINT) == 0
    else:
        statuses.clear()
        res = call(test_node, stop, Trigger.Request(), timeout=30)
        assert res.success, res.message
    took = time.monotonic() - t0
    cd = _info(bag)['custom_data']
    assert cd['closed_by'] == how and cd['drain'] == 'complete', cd
    msgs = read_mcap(bag)
    lost = 0
    for topic in SUITE:
        times = np.array([t for t, _ in msgs[f'/{topic}']])
        assert np.all(np.diff(times) > 0), topic           # no step twice, none misplaced
        assert times[0] == 0
        # The run: steps 0 .. 3 s at 1 ms; the applied current is published before each
        # step, so the paused run has none at 3 s.
        last = 2_999 if topic == 'solenoid_current' else 3_000
        assert times[-1] == last * MS, topic
        assert times.size + int(cd.get(f'lost./{topic}', 0)) == last + 1, (topic, cd)
        lost += int(cd.get(f'lost./{topic}', 0))
    assert int(cd['messages_lost']) == lost
    if freeze_at == 2.2:
        assert lost == 0
    else:
        assert lost > 1000          # 2.5 s of 1 kHz against the publishers' 1000 samples
    if how == 'stop':               # the recorder lives on, and says so
        spin_until(test_node, lambda: any('last_bag_lost' in {v.key for v in st.values}
                                          for st in statuses), 10, 'the diagnostics')
        st = next(st for st in statuses if 'last_bag_lost' in {v.key for v in st.values})
        kv = {v.key: v.value for v in st.values}
        assert st.level == DiagnosticStatus.WARN and int(kv['last_bag_lost']) == lost
        assert f'the last bag lost {lost} messages' in st.message
        assert rec.stop() == 0
    assert 'Traceback' not in rec.log()
    sim.stop()
    print(f'\nfrozen at {freeze_at} s, {how}: drained and closed in {took:.2f} s, {lost} lost')


@pytest.mark.ros
def test_a_paced_run_stopped_by_sigint_ends_at_the_signal(nodes, test_node, tmp_path):
    """The simulator runs on after the signal: the bag ends at the /clock published when
    the signal came (between the one published when it was sent and the one published when
    the recorder had exited), nothing after, and the drain does not wait for its bound."""
    rec, sim, clocks, bag = _paced_run(nodes, test_node, tmp_path, 0.0)
    spin_until(test_node, lambda: clocks.samples and clocks.latest >= 1.0, 60,
               'one second of run')
    t0, sent = time.monotonic(), time.time_ns()
    assert rec.stop(signal.SIGINT) == 0
    took, exited = time.monotonic() - t0, time.time_ns()
    _spin_for(test_node, 0.2)          # every /clock published until then
    sim.stop()
    lo, hi = clocks.at(sent), clocks.at(exited)
    cd = _info(bag)['custom_data']
    assert cd['drain'] == 'complete' and cd['messages_lost'] == '0', cd
    ends = {t: max(x for x, _ in v) * 1e-9 for t, v in read_mcap(bag).items()}
    for topic in SUITE:
        assert lo <= ends[f'/{topic}'] <= hi, (topic, lo, ends, hi)
    assert len({round(e, 3) for t, e in ends.items() if t != '/solenoid_current'}) == 1
    assert took < 1.5


@pytest.mark.ros
def test_a_recording_of_half_a_second_holds_half_a_second(nodes, test_node, tmp_path):
    """~/start, 0.5 s, ~/stop on a recorder that is already taking a paced run: the bag holds
    every step between the two calls, none after the stop."""
    from diagnostic_msgs.msg import DiagnosticArray
    from std_srvs.srv import Trigger
    spin_until(test_node, lambda: test_node.count_publishers('line_flow') == 0, 30,
               'the graph to forget earlier simulators')
    sim = nodes.start('simulator')
    wait_for_publisher(test_node, 'line_flow')
    rec = nodes.start('recorder', '-p', f'output:={tmp_path / "r"}', '-p', 'autostart:=false',
                      '-p', 'topics:=[' + ', '.join(SUITE) + ']')
    clocks = ClockLog(test_node)
    taken = []
    test_node.create_subscription(DiagnosticArray, '/diagnostics', lambda m: taken.extend(
        int({v.key: v.value for v in st.values}.get('messages', 0))
        for st in m.status if st.name == 'recorder'), 10)
    start = test_node.create_client(Trigger, 'recorder/start')
    stop = test_node.create_client(Trigger, 'recorder/stop')
    # A first recording until data flows (a writer can match its reader a while after the
    # reader matched it): then the recorder is taking.
    assert call(test_node, start, Trigger.Request()).success
    spin_until(test_node, lambda: taken and taken[-1] > 0, 30, 'the recorder to take data')
    assert call(test_node, stop, Trigger.Request(), timeout=30).success
    spin_until(test_node, lambda: len(clocks.samples) > 100, 30, '/clock here')
    asked = time.time_ns()
    assert call(test_node, start, Trigger.Request()).success
    opened = time.time_ns()
    _spin_for(test_node, 0.5)
    sent = time.time_ns()
    res = call(test_node, stop, Trigger.Request(), timeout=30)
    assert res.success, res.message
    answered = time.time_ns()
    _spin_for(test_node, 0.2)
    rec.stop()
    sim.stop()
    # What the simulator had published when the calls were made and answered.
    start_lo, start_hi = clocks.at(asked), clocks.at(opened)
    stop_lo, stop_hi = clocks.at(sent), clocks.at(answered)
    bag = tmp_path / 'r_1'
    cd = _info(bag)['custom_data']
    assert cd['closed_by'] == 'stop' and cd['messages_lost'] == '0', cd
    msgs = read_mcap(bag)
    for topic in SUITE:
        times = np.array([t for t, _ in msgs[f'/{topic}']]) * 1e-9
        assert np.allclose(np.diff(times), 1e-3, atol=1e-9), topic
        # Opened while the run went on: where the bag starts depends on what the take loop
        # had in hand then, within its few milliseconds.
        assert start_lo - 0.02 <= times[0] <= start_hi + 0.02, (topic, start_lo, times[0],
                                                                start_hi)
        assert stop_lo <= times[-1] <= stop_hi, (topic, stop_lo, times[-1], stop_hi)


def test_a_bag_started_mid_run_leaves_out_what_was_sent_before_its_first_clock(tmp_path):
    """A recording opened between a step's /clock and its unstamped messages: those belong
    to a step before the bag, never to its first /clock's."""
    topics = ['/a']
    rec = _recorder(tmp_path, topics)
    rec.start()
    rec.message('/a', False, _float(), {'source_timestamp': 10_001,
                                        'publication_sequence_number': 2})   # of step 1
    for k in range(2, 5):
        _step(rec, k, 10_000 * k, topics, k + 1)
        rec.advance(1)
    path, _ = rec.finish_stop() if rec.request_stop(0.5, wall_ns=45_000) else (None, 0)
    assert [t // MS for t, _ in read_mcap(path)['/a']] == [2, 3, 4]
    assert _info(path)['custom_data']['messages_lost'] == '0'


def test_a_message_sent_ahead_of_the_simulators_first_step_belongs_to_it(tmp_path):
    """The first /clock of the bag is its writer's first sample (sequence number 1): nothing
    came before it, so a command sent just before it (a controller answering the instant
    t = 0 ahead of its /clock) is of that step."""
    topics = ['/a']
    rec = _recorder(tmp_path, topics)
    rec.start()
    rec.message('/a', False, _float(), {'source_timestamp': 5,
                                        'publication_sequence_number': 1})
    for k in range(3):
        _step(rec, k, 10_000 * (k + 1), topics, k + 2)
        rec.advance(1)
    path, _ = rec.finish_stop() if rec.request_stop(0.5, wall_ns=35_000) else (None, 0)
    assert [t // MS for t, _ in read_mcap(path)['/a']] == [0, 0, 1, 2]


def test_a_stop_waits_for_a_topic_still_on_its_way_not_for_one_that_had_ended(tmp_path):
    """stop_time 9 ms. /a has delivered every step; /b stalled at 4 ms (its publisher will
    repair the rest, later than idle_timeout: a writer's heartbeat can be 3 s); /c publishes
    before each step, so 8 ms is its last before 9 ms; /d ended long before the stop. The
    bag waits for /b alone, then closes complete."""
    topics = ['/a', '/b', '/c', '/d']
    rec = _recorder(tmp_path, topics, idle_timeout=0.05)
    rec.start()

    def send(t, k):
        rec.message(t, True, _clock(k * MS), {'source_timestamp': 10_000 * k + 1})

    for k in range(10):
        if k == 3:                             # /d has ended: silent beyond idle_timeout
            end = time.monotonic() + 0.2
            while time.monotonic() < end:
                rec.advance(1)
                time.sleep(0.005)
        rec.clock(_clock(k * MS), {'source_timestamp': 10_000 * k,
                                   'publication_sequence_number': k + 1})
        send('/a', k)
        if k <= 4:
            send('/b', k)
        if k <= 8:
            send('/c', k)
        if k <= 2:
            send('/d', k)
        rec.advance(1)
    assert rec.request_stop(5.0, until_ns=9 * MS, reason='stop_time')
    end = time.monotonic() + 0.4               # /b's repair takes longer than idle_timeout
    while time.monotonic() < end:
        rec.advance(1)
        time.sleep(0.005)
    assert rec.stopping                        # /b still to come
    for k in range(5, 10):
        send('/b', k)
    rec.advance(1)
    assert not rec.stopping
    path, _ = rec.closed[-1]
    cd = _info(path)['custom_data']
    assert cd['drain'] == 'complete' and cd['closed_by'] == 'stop_time'
    msgs = read_mcap(path)
    assert [len(msgs[t]) for t in topics] == [10, 10, 9, 3]
