"""SIGTERM to ``hydropump-demo`` while its graphs run: it stops them, every node process it
started ended by PID, and exits with code 143 (128 + SIGTERM) and one line saying so, with no
traceback.

``ros2 run`` and ``ros2 launch`` forward SIGINT only; a service manager, ``timeout`` or
``kill`` send SIGTERM, and the demo's nodes are its own children: nothing else ends them.
"""

import os
from pathlib import Path
import queue
import signal
import subprocess
import sys
import threading
import time

import pytest

pytestmark = [pytest.mark.ros, pytest.mark.slow]

DEMO = Path(sys.executable).with_name('hydropump-demo')
# The graph of the paper's campaign, and the Fig. 1 and excavator graphs beside it (each in
# a worker process).
GRAPHS = 3


def children(pid: int) -> list[int]:
    out = []
    for task in Path(f'/proc/{pid}/task').glob('*/children'):
        try:
            out += [int(x) for x in task.read_text().split()]
        except (OSError, ValueError):  # the process or thread has just ended
            pass
    return out


def _stat(pid: int) -> list[str]:
    """The fields of /proc/<pid>/stat after the command name (state first); [] if gone."""
    try:
        return Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()
    except (OSError, IndexError):
        return []


def descendants(pid: int) -> dict[tuple[int, str], str]:
    """Every process below ``pid``, by (PID, start time: a PID used again is another
    process): its command line."""
    out, todo = {}, [pid]
    while todo:
        for child in children(todo.pop()):
            try:
                cmd = Path(f'/proc/{child}/cmdline').read_text().replace('\0', ' ')
            except OSError:
                continue
            stat = _stat(child)
            if stat:
                out[child, stat[19]] = cmd
                todo.append(child)
    return out


def alive(proc: tuple[int, str]) -> bool:
    """Is this process (PID, start time) still there, and not a zombie?"""
    stat = _stat(proc[0])
    return bool(stat) and stat[19] == proc[1] and stat[0] != 'Z'


@pytest.fixture
def domain():
    """A ROS domain held for this test (the coordinator's): the demo's main graph runs in
    the ROS_DOMAIN_ID it is given."""
    from domain_coordinator import domain_id
    with domain_id() as did:
        yield did


@pytest.mark.skipif(not Path('/proc/self/task').is_dir(), reason='needs Linux /proc')
def test_sigterm_stops_every_graph_of_the_demo(tmp_path, domain):
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST', ROS_DOMAIN_ID=str(domain))
    proc = subprocess.Popen([str(DEMO), '--quick', '--out', str(tmp_path / 'run')],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    lines: queue.Queue = queue.Queue()
    errors: list[str] = []
    threading.Thread(target=lambda: [lines.put(ln) for ln in proc.stdout] + [lines.put(None)],
                     daemon=True).start()
    drain = threading.Thread(target=lambda: errors.extend(proc.stderr), daemon=True)
    drain.start()
    started: dict[tuple[int, str], str] = {}
    try:
        # Up: every graph has said 'ready in' (their nodes answer). The processes are taken
        # as each graph comes up: on a busy machine a quick graph can finish its work
        # before the last one is up, and its nodes are then already gone (as they should).
        out, ready, deadline = [], 0, time.monotonic() + 90
        while ready < GRAPHS:
            line = lines.get(timeout=max(0.1, deadline - time.monotonic()))
            assert line is not None, 'the demo ended before its graphs were up:\n' + \
                ''.join(out + errors)
            out.append(line)
            if 'ready in' in line:
                ready += 1
                started.update(descendants(proc.pid))
        # Three node processes a graph besides the workers and the resource tracker.
        nodes = {p: c for p, c in started.items() if 'multiprocessing' not in c}
        assert len(nodes) >= 3 * GRAPHS, started
        proc.send_signal(signal.SIGTERM)
        try:
            rc = proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            pytest.fail(f'hydropump-demo did not end within 20 s of SIGTERM: {started}')
        left = [p for p in nodes if alive(p)]
        while (line := lines.get(timeout=5)) is not None:
            out.append(line)
        drain.join(timeout=5)
        err = ''.join(errors)
        assert rc == 143, (rc, err)
        assert 'Traceback' not in ''.join(out) + err, ''.join(out) + err
        assert [ln for ln in err.splitlines() if 'SIGTERM' in ln] == \
            [f'stopped by SIGTERM: every node of the run ended; the partial run is in '
             f'{tmp_path / "run"}'], err
        assert not left, f'node processes left running: {[nodes[p] for p in left]}'
        # The pool's helpers (workers, resource tracker) end with the demo's pipes.
        deadline = time.monotonic() + 5
        while any(alive(p) for p in started) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert not [p for p in started if alive(p)], started
    finally:
        if proc.poll() is None:
            proc.kill()
        for p in started:  # by PID, and only the very process seen here
            if alive(p):
                os.kill(p[0], signal.SIGKILL)
        proc.wait()
