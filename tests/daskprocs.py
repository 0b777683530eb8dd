"""A Dask cluster started as a user starts one: ``dask scheduler`` and ``dask worker`` as
processes on localhost, ended by the ids of the processes started here."""

from collections.abc import Iterator
from contextlib import contextmanager
import os
from pathlib import Path
import re
import signal
import subprocess
import sys
import time

BIN = Path(sys.executable).parent


def _start(args):
    return subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            start_new_session=True)


def _stop(proc):
    # By the id of the process started here (its session: the worker's child too).
    if proc.poll() is None:
        os.killpg(proc.pid, signal.SIGTERM)
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(5)


@contextmanager
def external_cluster(workers: int) -> Iterator[str]:
    """The scheduler's address, once ``workers`` worker processes (one thread each) are up."""
    sched = _start([str(BIN / 'dask'), 'scheduler', '--port', '0', '--no-dashboard',
                    '--host', '127.0.0.1'])
    worker = None
    try:
        address, t0 = None, time.monotonic()
        while address is None and time.monotonic() - t0 < 30:
            m = re.search(r'Scheduler at:\s+(tcp://\S+)', sched.stdout.readline())
            address = m.group(1) if m else None
        assert address, 'the scheduler did not report its address'
        worker = _start([str(BIN / 'dask'), 'worker', address, '--nworkers', str(workers),
                         '--nthreads', '1', '--no-dashboard'])
        from dask.distributed import Client
        with Client(address, timeout=10, set_as_default=False) as c:
            c.wait_for_workers(workers, timeout=60)
        yield address
    finally:
        for proc in (worker, sched):
            if proc is not None:
                _stop(proc)
