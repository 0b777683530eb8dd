"""``hydropump-demo`` on a disk that fills: the run folder on a small file system of its own
(a tmpfs), filled to the last byte once the bags are recorded, as the run reaches its figures.
The demo keeps its bags and says which stage failed: one ``error:`` line naming the stage, the
file and where the bags are, exit code 1, no traceback; every bag recorded before is there and
whole (closed, its summary and metadata.yaml agreeing, as long as its experiment), and no file
is left half-written."""

import errno
import os
from pathlib import Path
import queue
import re
import signal
import subprocess
import sys
import threading
import time

import pytest
import yaml

pytestmark = [pytest.mark.ros, pytest.mark.slow]

DEMO = Path(sys.executable).with_name('hydropump-demo')
# What --quick runs (README, hydropump-demo --help): three identification staircases of four
# 0.6 s stairs, and EMC on the three closed-loop scenarios, 1.2 s each.
QUICK = {**{f'ident_{i}': 4 * 0.6 for i in (1, 2, 3)},
         **{f'emc_{s}': 1.2 for s in ('flow_step', 'aperture_step', 'margin_step')}}
SIZE = 64 * 2**20  # bytes: the run folder of --quick --no-fig1 --no-excavator: about 4 MB


@pytest.fixture
def small_disk(tmp_path):
    """A file system of its own, :data:`SIZE` bytes (a tmpfs: mounting needs root)."""
    if os.geteuid() != 0:
        pytest.skip('a small file system of its own needs root (mount -t tmpfs); a full disk '
                    'cannot be made for the whole demo otherwise')
    mnt = tmp_path / 'disk'
    mnt.mkdir()
    proc = subprocess.run(['mount', '-t', 'tmpfs', '-o', f'size={SIZE}', 'tmpfs', str(mnt)],
                          capture_output=True, text=True)
    if proc.returncode:
        pytest.skip(f'cannot mount a tmpfs here: {proc.stderr.strip()}')
    try:
        yield mnt
    finally:
        if subprocess.run(['umount', str(mnt)]).returncode:
            subprocess.run(['umount', '-l', str(mnt)])


def fill(folder: Path) -> None:
    """Fill ``folder``'s file system to the last byte."""
    with open(folder / 'filler', 'wb', buffering=0) as f:
        for size in (2**20, 4096, 1):
            block = bytes(size)
            try:
                while True:
                    f.write(block)
            except OSError as exc:
                assert exc.errno == errno.ENOSPC, exc
    assert os.statvfs(folder).f_bavail == 0


def test_a_disk_that_fills_keeps_the_bags_and_names_the_stage(small_disk):
    from mcap.reader import make_reader
    run = small_disk / 'run'
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
    proc = subprocess.Popen([str(DEMO), '--quick', '--no-fig1', '--no-excavator', '--out',
                             str(run)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    lines: queue.Queue = queue.Queue()
    threading.Thread(target=lambda: [lines.put(ln) for ln in proc.stdout] + [lines.put(None)],
                     daemon=True).start()
    errors: list[str] = []
    drain = threading.Thread(target=lambda: errors.extend(proc.stderr), daemon=True)
    drain.start()
    out = []
    try:
        # The model analysis writes nothing and takes a second or so; the figures come next.
        # The demo is held (SIGSTOP) while its disk fills.
        deadline = time.monotonic() + 300
        while True:
            line = lines.get(timeout=max(0.1, deadline - time.monotonic()))
            assert line is not None, 'the demo ended before its model analysis:\n' + \
                ''.join(out + errors)
            out.append(line)
            if line.startswith('[4/5 model analysis]'):
                break
        proc.send_signal(signal.SIGSTOP)
        try:
            fill(small_disk)
        finally:
            proc.send_signal(signal.SIGCONT)
        rc = proc.wait(timeout=120)
        while (line := lines.get(timeout=10)) is not None:
            out.append(line)
        drain.join(timeout=10)
    finally:
        if proc.poll() is None:  # a failed test: the demo stops its graphs on SIGTERM
            proc.send_signal(signal.SIGCONT)
            proc.send_signal(signal.SIGTERM)
            try:
                proc.wait(timeout=90)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
    err = ''.join(errors)
    assert 'Traceback' not in ''.join(out) + err, ''.join(out) + err
    assert rc == 1, (rc, err)
    bags = run / 'bags'
    (line,) = err.splitlines()
    m = re.fullmatch(r'error: the figures stage failed: cannot write the figure (\S+): No '
                     rf'space left on device; the 6 bags recorded before it are kept in '
                     rf'{re.escape(str(bags))}', line)
    assert m, line
    # The figure it could not write is not there, half-written or empty, nor is its
    # temporary file, nor the report the run never reached.
    figure = Path(m[1])
    assert figure.parent == run / 'figures' and not figure.exists()
    assert not [p for p in run.rglob('*') if '.part-' in p.name]
    assert not (run / 'report.html').exists() and not (run / 'summary.json').exists()
    # Every bag of the run, whole: closed (the summary MCAP writes on closing), holding what
    # the recorder's metadata.yaml counts, over its experiment's duration.
    assert sorted(p.name for p in bags.iterdir()) == sorted(QUICK)
    for name, duration in QUICK.items():
        meta = yaml.safe_load((bags / name / 'metadata.yaml').read_text())[
            'rosbag2_bagfile_information']
        with open(bags / name / f'{name}_0.mcap', 'rb') as f:
            stats = make_reader(f).get_summary().statistics
        assert stats.message_count == meta['message_count'] > 0, name
        span = (stats.message_end_time - stats.message_start_time) * 1e-9
        assert abs(span - duration) <= 0.011, (name, span, duration)
