"""Bags checked against the pump before any fit: ``hydropump fit``, ``calibrate`` and
``validate`` refuse a bag in the wrong units, with the wrong message types, holding two runs
or too few samples, each with one ``error:`` line and exit code 2, and write nothing a user
could take for a result. The bags are written with the project's writer (``write_bag``,
``BagWriter``), as the recorder writes them."""

import json

import numpy as np
import pytest

from hydropump_ctrl.bag import BagWriter, qos_profile, typestore, write_bag
from hydropump_ctrl.cli import main
from hydropump_ctrl.ident import recording_to_bag
from hydropump_ctrl.ident import synthetic as syn

F64, PRESSURE = 'std_msgs/msg/Float64', 'sensor_msgs/msg/FluidPressure'
P_ATM = 101325.0              # config/pump.yaml
T0 = 1.0                      # s: bags start at a non-zero simulation time


@pytest.fixture(scope='module')
def rec():
    """Eight seconds of a staircase and its FOPDT flow (G0 = 100 %), in SI."""
    return syn.make_record(syn.Truth(100.0, 0.100, 0.055), seed=4, duration=8.0)


def _streams(rec, *, current=1.0, flow=1.0, pressure=lambda p: p, types=None):
    """The recorder's topics of ``rec`` with a line pressure, scaled as a careless logger
    would write them."""
    t = rec.t + T0
    line_p = 1.5e7 + P_ATM + 1e9 * rec['line_flow']            # Pa absolute
    types = types or {}
    return {'/solenoid_current': (types.get('current', F64), t, current * rec['solenoid_current']),
            '/line_flow': (types.get('flow', F64), t, flow * rec['line_flow']),
            '/line_pressure': (PRESSURE, t, pressure(line_p))}


def _run(capsys, *argv):
    code = main([str(a) for a in argv])
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    return code, lines


def _fit(capsys, bag, tmp_path):
    return _run(capsys, 'fit', bag, '--no-progress', '--out', tmp_path / 'fit')


def _calibrate(capsys, bag, tmp_path, *extra):
    return _run(capsys, 'calibrate', bag, '--free', 'line.mu_u', '--report',
                tmp_path / 'cal', '--no-plots', '--no-progress', *extra)


def _one_error(code, lines, *words):
    assert code == 2, lines
    assert len(lines) == 1 and lines[0].startswith('error: '), lines
    for w in words:
        assert w in lines[0], (w, lines[0])


def test_a_good_bag_still_fits(rec, tmp_path, capsys):
    bag = recording_to_bag(rec, tmp_path / 'good', start_s=T0)
    code = main(['fit', str(bag), '--json', '--no-report', '--no-progress'])
    out, err = capsys.readouterr()
    assert code == 0, err
    (fit,) = json.loads(out)['sets']
    assert fit['G0'] == pytest.approx(100.0, abs=1.0) and fit['flags'] == []
    assert 'error' not in err


def test_current_in_ma_is_refused_by_fit_and_calibrate(rec, tmp_path, capsys):
    bag = write_bag(tmp_path / 'ma', _streams(rec, current=1e3))
    _one_error(*_fit(capsys, bag, tmp_path), str(bag), 'solenoid_current', 'looks like mA',
               'I_limits = 0.1 .. 0.9 A')
    assert not (tmp_path / 'fit' / 'result.json').exists()
    _one_error(*_calibrate(capsys, bag, tmp_path), 'looks like mA')
    assert not (tmp_path / 'cal' / 'calibrated.yaml').exists()


def test_flow_in_l_per_min_is_refused(rec, tmp_path, capsys):
    bag = write_bag(tmp_path / 'lpm', _streams(rec, flow=6e4))
    _one_error(*_fit(capsys, bag, tmp_path), 'line_flow', 'looks like L/min', '6e4',
               'Q_max = V_p f_p')
    assert not (tmp_path / 'fit' / 'result.json').exists()


@pytest.mark.parametrize('convert, words', [
    (lambda p: p / 1e5, ('line_pressure', 'looks like bar', 'Pa absolute')),
    # Gauge: an unloaded line reads 0 Pa for two seconds, where absolute reads p_atm.
    (lambda p: np.where(np.arange(p.size) < 2000, 0.0, p - P_ATM),
     ('line_pressure', 'below atmospheric', 'looks like gauge', 'add 101325 Pa')),
])
def test_pressure_in_bar_or_gauge_is_refused_by_calibrate_and_validate(rec, tmp_path, capsys,
                                                                       convert, words):
    bag = write_bag(tmp_path / 'p', _streams(rec, pressure=convert))
    _one_error(*_calibrate(capsys, bag, tmp_path), *words)
    assert not (tmp_path / 'cal' / 'calibrated.yaml').exists()
    _one_error(*_run(capsys, 'validate', bag, '--out', tmp_path / 'val', '--no-plots',
                     '--no-progress'), *words)
    assert not (tmp_path / 'val' / 'validation.md').exists()


def test_bar_and_l_per_min_together_give_a_line_each(rec, tmp_path, capsys):
    bag = write_bag(tmp_path / 'both', _streams(rec, flow=6e4, pressure=lambda p: p / 1e5))
    code, lines = _calibrate(capsys, bag, tmp_path)
    assert code == 2 and len(lines) == 2 and all(ln.startswith('error: ') for ln in lines)
    assert any('looks like L/min' in ln for ln in lines)
    assert any('looks like bar' in ln for ln in lines)


@pytest.mark.parametrize('types, topic', [
    ({'flow': PRESSURE}, '/line_flow'),
    ({'current': PRESSURE, 'flow': PRESSURE}, '/solenoid_current'),
])
def test_the_wrong_message_type_on_a_known_topic_is_refused(rec, tmp_path, capsys, types,
                                                            topic):
    bag = write_bag(tmp_path / 'types', _streams(rec, types=types))
    _one_error(*_fit(capsys, bag, tmp_path), f'topic {topic} ({PRESSURE})',
               'wrong message type', 'std_msgs/msg/Float64')
    _one_error(*_calibrate(capsys, bag, tmp_path), 'wrong message type')


def test_time_going_back_is_refused_with_where(rec, tmp_path, capsys):
    # A simulator restarted under one recorder: the second run's 240 steps are written
    # after the first run, their times starting again from the first's.
    s = _streams(rec)
    n2 = 240
    ts = typestore()
    bag = tmp_path / 'two'
    with BagWriter(bag, compression='none') as w:
        for topic, (msgtype, _, _) in s.items():
            w.add_topic(topic, msgtype, [qos_profile(history='keep_last', depth=10)])
        for k in [*range(rec.t.size), *range(n2)]:
            for topic, (msgtype, t, v) in s.items():
                ns = int(round(t[k] * 1e9))
                cls = ts.types[msgtype]
                msg = cls(data=float(v[k])) if msgtype == F64 else cls(
                    header=ts.types['std_msgs/msg/Header'](
                        stamp=ts.types['builtin_interfaces/msg/Time'](
                            sec=ns // 10**9, nanosec=ns % 10**9), frame_id=''),
                    fluid_pressure=float(v[k]), variance=0.0)
                w.write(topic, ns, ts.serialize_cdr(msg, msgtype))
    for argv in (('fit', bag, '--no-report', '--no-progress'),
                 ('calibrate', bag, '--free', 'line.mu_u', '--report', tmp_path / 'cal',
                  '--no-progress')):
        _one_error(*_run(capsys, *argv), str(bag), 'time goes back', 'to 0 s',
                   f'{n2} messages repeat', 'from message 1 of', 'two runs',
                   'record each run in its own bag')
    assert not (tmp_path / 'cal' / 'calibrated.yaml').exists()
    # The same run appended by a writer that sorts by time.
    t, cur, flow = rec.t + T0, rec['solenoid_current'], rec['line_flow']
    sorted_bag = write_bag(tmp_path / 'two_sorted', {
        '/solenoid_current': (F64, np.r_[t, t[:n2]], np.r_[cur, cur[:n2]]),
        '/line_flow': (F64, np.r_[t, t[:n2]], np.r_[flow, flow[:n2]])})
    _one_error(*_fit(capsys, sorted_bag, tmp_path), 'time goes back', 'two runs')


def test_a_stamp_repeated_here_and_there_is_not_two_runs(rec, tmp_path, capsys):
    t, cur, flow = rec.t + T0, rec['solenoid_current'], rec['line_flow']
    again = np.arange(0, t.size, 1000)                  # 8 messages sent twice
    bag = write_bag(tmp_path / 'resent', {
        '/solenoid_current': (F64, np.r_[t, t[again]], np.r_[cur, cur[again]]),
        '/line_flow': (F64, np.r_[t, t[again]], np.r_[flow, flow[again]])})
    code, lines = _run(capsys, 'fit', bag, '--no-report', '--no-progress')
    assert code == 0, lines
    assert any('8 repeated time stamps dropped' in ln for ln in lines), lines


def test_too_few_samples_say_how_many_and_how_many_are_needed(rec, tmp_path, capsys):
    t = rec.t[:3] + T0
    bag = write_bag(tmp_path / 'three', {
        '/solenoid_current': (F64, t, rec['solenoid_current'][:3]),
        '/line_flow': (F64, t, rec['line_flow'][:3]),
        '/line_pressure': (PRESSURE, t, np.full(3, 1.5e7))})
    for code, lines in (_fit(capsys, bag, tmp_path), _calibrate(capsys, bag, tmp_path)):
        _one_error(code, lines, str(bag), '3 samples', 'at least 50')
        assert 'it has' not in lines[0] and 'none of' not in lines[0]
    one = write_bag(tmp_path / 'one', {'/solenoid_current': (F64, t[:1], [0.5]),
                                       '/line_flow': (F64, t[:1], [5e-4])})
    _one_error(*_fit(capsys, one, tmp_path), '1 flow message(s)', 'at least 50')


def test_a_compared_signal_with_too_few_samples_says_so(rec, tmp_path, capsys):
    # The line pressure has 3 messages: present, but nothing to compare.
    s = _streams(rec)
    _, t, p = s['/line_pressure']
    s['/line_pressure'] = (PRESSURE, t[:3], p[:3])
    bag = write_bag(tmp_path / 'short_p', s)
    _one_error(*_calibrate(capsys, bag, tmp_path, '--signals', 'line_pressure'),
               'no output to compare', 'line_pressure 3', 'more than 10')


def test_a_calibration_worse_than_the_mean_is_written_and_flagged_not_blamed_on_units(
        tmp_path, capsys):
    # Plausible units, but the flow falls where the current rises: no parameter of the
    # model makes it fit, and the fit % comes out negative. The fit still improves on the
    # start, so the file is written, with the flag in its header and on stderr; nothing
    # blames the units, which the plausibility checks passed.
    t = T0 + np.arange(3000) * 1e-3
    rng = np.random.default_rng(0)
    up = t >= T0 + 1.0
    bag = write_bag(tmp_path / 'wrong', {
        '/solenoid_current': (F64, t, np.where(up, 0.54, 0.46)),
        '/line_flow': (F64, t, np.where(up, 4.0e-4, 6.5e-4) + 2e-6 * rng.standard_normal(t.size))})
    code, lines = _calibrate(capsys, bag, tmp_path)
    assert code == 0, lines
    warned = [ln for ln in lines if 'below zero' in ln]
    assert warned and 'line_flow fit' in warned[0], lines
    assert not any('units of the bags' in ln or 'wrong units' in ln for ln in lines), lines
    header = (tmp_path / 'cal' / 'calibrated.yaml').read_text().split('/**')[0]
    assert 'flag: wrong: line_flow fit' in header
    report = (tmp_path / 'cal' / 'report.md').read_text()
    assert 'is below zero' in report


# ---- what the recorder told in the bag -------------------------------------------------------

CLEAN = {'time_base': 'simulation', 'messages_lost': '0', 'messages_late': '0',
         'closed_by': 'stop', 'drain': 'complete', 'events.safe_current': '0',
         'events.lock_step_timeout': '0'}


def test_a_bag_whose_recorder_saw_no_event_and_lost_nothing_fits(rec, tmp_path, capsys):
    bag = write_bag(tmp_path / 'clean', _streams(rec), custom_data=CLEAN)
    code, lines = _fit(capsys, bag, tmp_path)
    assert code == 0, lines


@pytest.mark.parametrize('told, words', [
    ({'events.safe_current': '2', 'events.safe_current.first': '3.250000'},
     ('2 safe-current engagements (the first at 3.25 s)',)),
    ({'events.lock_step_timeout': '1', 'events.lock_step_timeout.first': '1.005000'},
     ('1 lock-step timeout (the first at 1.005 s)',)),
    ({'messages_lost': '7', 'lost./line_flow': '5', 'lost./line_pressure': '2'},
     ('7 messages lost (/line_flow 5, /line_pressure 2)',)),
    ({'messages_lost': '3', 'lost./line_flow': '3',
      'drain': 'cut after 2 s: what was still on its way is counted as lost'},
     ('3 messages lost', 'its stop was cut after 2 s')),
    ({'events.safe_current': '1', 'events.safe_current.first': '2.000000',
      'events.lock_step_timeout': '4', 'events.lock_step_timeout.first': '0.500000',
      'messages_lost': '1', 'lost./line_flow': '1'},
     ('1 safe-current engagement (the first at 2 s); 4 lock-step timeouts (the first at 0.5 '
      's); 1 messages lost',)),
])
def test_a_bag_whose_recorder_reports_events_or_losses_is_refused(rec, tmp_path, capsys, told,
                                                                 words):
    """Safe-current engagements, lock-step timeouts and losses leave data that fit as well
    as any: every fit refuses them, one line naming what, how many and when the first was."""
    bag = write_bag(tmp_path / 'told', _streams(rec), custom_data={**CLEAN, **told})
    _one_error(*_fit(capsys, bag, tmp_path), str(bag), 'its recorder reports', *words)
    assert not (tmp_path / 'fit' / 'result.json').exists()
    _one_error(*_calibrate(capsys, bag, tmp_path), 'its recorder reports', *words)
    assert not (tmp_path / 'cal' / 'calibrated.yaml').exists()


def test_the_report_is_read_from_the_mcap_file_alone(rec, tmp_path, capsys):
    """Given the storage file only (no metadata.yaml beside it), the recorder's report comes
    from the file's last rosbag2 metadata record, as ros2 bag reindex would rebuild it."""
    bag = write_bag(tmp_path / 'alone', _streams(rec),
                    custom_data={**CLEAN, 'events.safe_current': '1',
                                 'events.safe_current.first': '4.000000'})
    (bag / 'metadata.yaml').unlink()
    (mcap,) = bag.glob('*.mcap')
    _one_error(*_fit(capsys, mcap, tmp_path), str(mcap), '1 safe-current engagement')
