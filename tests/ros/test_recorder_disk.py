"""The recorder over real DDS when its disk fills: a file-size limit (RLIMIT_FSIZE, as a full
disk for the recorder alone, no root needed) makes a write fail in the middle of a full-rate
recording. The recorder reports ERROR on /diagnostics, answers ~/stop with the reason, and
exits with one error line and exit code 3, leaving a bag the project's reader reads."""

import resource
import signal
import time

import pytest

from .rosutil import call, NodeProcess, spin_until, wait_for_publisher

pytestmark = pytest.mark.ros

SUITE = ('solenoid_current', 'pump_flow', 'line_flow', 'load_flow', 'actuator_pressure',
         'line_pressure', 'load_pressure', 'joint_states')
LIMIT = 3 * 1024 * 1024  # bytes: a few seconds of a full-rate run, uncompressed


def _file_size_limit():
    """In the child: writes past LIMIT fail with EFBIG instead of killing the process."""
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    resource.setrlimit(resource.RLIMIT_FSIZE, (LIMIT, LIMIT))


def test_a_full_disk_ends_the_recording_with_a_readable_bag_and_the_reason(
        nodes, test_node, tmp_path):
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
    from std_srvs.srv import Trigger

    from hydropump_ctrl.ident import read_recordings
    bag = tmp_path / 'full'
    statuses = []

    def on_diag(msg):
        statuses.extend(st for st in msg.status if st.name == 'recorder')
    test_node.create_subscription(DiagnosticArray, '/diagnostics', on_diag, 10)
    stop = test_node.create_client(Trigger, 'recorder/stop')
    nodes.start('simulator')                   # paced, every topic at 1 kHz
    wait_for_publisher(test_node, 'line_flow')
    rec = NodeProcess('recorder', ['-p', f'output:={bag}', '-p', 'compression:=none',
                                   '-p', f'topics:=[{", ".join(SUITE)}]'], tmp_path,
                      preexec_fn=_file_size_limit)
    try:
        spin_until(test_node, stop.service_is_ready, 30, 'the recorder stop service')
        spin_until(test_node, lambda: any(st.level == DiagnosticStatus.ERROR
                                          for st in statuses) or not rec.alive(), 120,
                   'the recorder to report the failed write')
        # The reason on /diagnostics, and ~/stop answers with it while the node is still up.
        (error,) = [st for st in statuses if st.level == DiagnosticStatus.ERROR][:1]
        assert error.message == 'write failed: File too large (EFBIG)'
        values = {kv.key: kv.value for kv in error.values}
        assert values['recording'] == 'False' and values['bag'] == str(bag)
        res = call(test_node, stop, Trigger.Request(), timeout=5)
        assert res.success is False
        assert res.message.startswith(f'recording failed: {bag}: cannot write: File too '
                                      'large (EFBIG)')
        # Then it exits on its own, within a bounded time.
        t0 = time.monotonic()
        while rec.alive() and time.monotonic() - t0 < 15:
            time.sleep(0.05)
        assert not rec.alive(), 'the recorder did not exit after a failed write'
    finally:
        code = rec.stop()
    log = rec.log()
    assert code == 3, log
    assert 'Traceback' not in log, log
    lines = [ln for ln in log.splitlines() if ln.startswith('error:')]
    assert len(lines) == 1 and lines[0].startswith(
        f'error: {bag}: cannot write: File too large (EFBIG); the bag is closed with the '), log
    # What was written before the failure is a bag the project's reader takes whole.
    assert (bag / 'full_0.mcap').stat().st_size <= LIMIT
    (recording,) = read_recordings([bag])           # it refuses a bag cut short
    assert not recording.truncated
    assert recording.t.size > 500                  # half a second of 1 kHz samples at least
