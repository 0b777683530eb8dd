"""Ctrl-C at any moment of a node's start-up, as a user gives it: the installed executable
(as ``ros2 run`` finds it, and the venv's ``bin/<node>``, tries alternating), SIGINT after
5 ms to 300 ms. Every try ends the process (a swallowed signal would leave it
running), with exit code 0 (the node's own handlers) or 130 / killed by SIGINT (before the
interpreter could take it), and never a traceback or a fatal error."""

import os
from pathlib import Path
import signal
import subprocess
import time

from ament_index_python.packages import get_package_prefix
import numpy as np
import pytest

from .rosutil import executable

pytestmark = pytest.mark.ros

TRIES = {'recorder': 25, 'simulator': 6, 'controller': 6}


@pytest.mark.parametrize('node', list(TRIES))
def test_ctrl_c_during_start_up_ends_the_node_cleanly(node, tmp_path, ros_domain):
    bad = []
    for k, delay in enumerate(np.linspace(0.005, 0.3, TRIES[node])):
        args = ['-p', f'output:={tmp_path / f"bag{k}"}'] if node == 'recorder' else []
        with open(tmp_path / f'{node}{k}.log', 'w+') as log:
            exe = executable(node) if k % 2 == 0 else str(
                Path(get_package_prefix('hydropump_ros')) / 'bin' / node)
            proc = subprocess.Popen([exe, '--ros-args', *args], stdout=log,
                                    stderr=subprocess.STDOUT, env=os.environ.copy())
            time.sleep(delay)
            proc.send_signal(signal.SIGINT)
            try:
                rc = proc.wait(timeout=20)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
                rc = 'still running 20 s after the signal'
            log.seek(0)
            text = log.read()
        if rc not in (0, 130, -signal.SIGINT) or 'Traceback' in text or 'Fatal' in text:
            bad.append(f'{exe}, {delay * 1e3:.0f} ms: exit {rc}\n{text[-600:]}')
    assert not bad, '\n'.join(bad)
