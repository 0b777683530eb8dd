"""The recorder's topics as a careless user gives them: an empty or invalid name ends start-up
with one error line, a typo is reported with the topic it probably meant."""

import subprocess

import pytest

from .rosutil import executable, spin_until, wait_for_publisher

pytestmark = pytest.mark.ros


@pytest.mark.parametrize('topics, name, why', [
    ("['']", '', 'topic name must not be empty string'),
    ("['line_flow', 'bad topic!!']", 'bad topic!!',
     'topic name must not contain characters other than'),
])
def test_an_invalid_topic_name_is_one_error_line_and_exit_2(tmp_path, ros_domain, topics,
                                                             name, why):
    proc = subprocess.run([executable('recorder'), '--ros-args', '-p',
                           f'output:={tmp_path / "bag"}', '-p', f'topics:={topics}'],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2, proc.stderr
    assert 'Traceback' not in proc.stderr + proc.stdout
    (line,) = [ln for ln in proc.stderr.splitlines() if ln.startswith('error:')]
    assert line.startswith(f'error: topics: {name!r} is not a valid topic name ({why}'), line
    assert not (tmp_path / 'bag').exists()


def test_a_topic_nobody_publishes_is_reported_with_the_one_meant(nodes, test_node, tmp_path):
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
    statuses = []
    test_node.create_subscription(
        DiagnosticArray, '/diagnostics',
        lambda msg: statuses.extend(st for st in msg.status if st.name == 'recorder'), 10)
    nodes.start('simulator')
    wait_for_publisher(test_node, 'line_flow')
    rec = nodes.start('recorder', '-p', f'output:={tmp_path / "bag"}',
                      '-p', 'topics:=[line_flow, lien_pressure]')
    note = 'no publisher on /lien_pressure after 5 s (did you mean /line_pressure?)'
    spin_until(test_node, lambda: any(st.level == DiagnosticStatus.WARN for st in statuses),
               60, 'the recorder to warn of the unpublished topic')
    warn = next(st for st in statuses if st.level == DiagnosticStatus.WARN)
    assert warn.message == note
    assert {kv.key: kv.value for kv in warn.values}['unpublished'] == '/lien_pressure'
    # Until then the topic that has a publisher was not reported.
    assert all(st.level == DiagnosticStatus.OK for st in statuses[:statuses.index(warn)])
    assert rec.stop() == 0
    log = rec.log()
    assert '[WARN]' in log and note in log and log.count('no publisher on') == 1, log
