"""One execution layer for batches of independent tasks: a sweep's runs, a calibration's
simulations and sensitivity columns, a fleet's pumps.

Two executors behind one interface (:class:`Executor`):

- :class:`InProcess` - in this process: a plain loop, or a few threads. Threads run in
  parallel only where the work releases the GIL, as the compiled simulations do (numba
  ``nogil``: a calibration's jobs are over 90 % compiled loop); they start at once and pickle
  nothing, so small jobs and jobs of many short tasks run here.
- :class:`DaskExecutor` - Dask distributed: a :class:`~dask.distributed.LocalCluster` of
  worker processes started here (one thread each: the work is single-threaded numba and
  Python), or the workers of a scheduler by address (``--scheduler``,
  ``DASK_SCHEDULER_ADDRESS``), which need this project installed in the same version.

:func:`open_executor` picks one from an address and a worker count. Where neither is given,
the caller decides with :func:`cluster_pays`: a local cluster costs a start-up
(:data:`LOCAL_START`, measured by ``bench/bench_sweep.py``) that only a long enough batch wins
back. Nothing here imports ROS.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
import logging
import os
from typing import Any

from hydropump_sim.errors import HydropumpError

#: Seconds to wait for a scheduler before giving up.
CONNECT_TIMEOUT = 5.0
#: Seconds a local cluster of two workers takes to start and to import and run its first
#: task in each worker: 1.4-2.6 s measured by ``bench/bench_sweep.py`` and
#: ``bench/bench_calibrate.py`` on a shared 2-core machine.
LOCAL_START = 2.5

#: The Dask setting that gives every worker a fixed malloc trim threshold (see
#: :func:`open_client`); None leaves glibc's own, adaptive one.
TRIM = 'distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_'


class SchedulerError(HydropumpError, ConnectionError):
    """The Dask scheduler cannot be reached (one line, naming its address)."""


def cores() -> int:
    """The cores this process may use."""
    try:
        return max(len(os.sched_getaffinity(0)), 1)
    except AttributeError:      # not on Linux
        return os.cpu_count() or 1


def cluster_pays(serial_seconds: float, workers: int, *, start: float = LOCAL_START,
                 efficiency: float = 0.8) -> bool:
    """Would a local cluster of ``workers`` processes finish a batch that takes
    ``serial_seconds`` in this process (run as it would run here) sooner, its start-up
    included? ``efficiency``: the measured speed-up per worker over that (below 1: the
    command and the scheduler share the cores; a sweep's runs against a plain loop: 0.88 on
    2 cores, ``bench/bench_sweep.py``)."""
    if workers < 2:
        return False
    speedup = max(workers * efficiency, 1.0)
    return serial_seconds - serial_seconds / speedup > start


class Executor:
    """Where a batch of tasks runs (see the module).

    ``map`` and ``stream`` call ``fn(item, **shared)`` for every item; values in ``shared``
    are the same for every task: pass large ones through :meth:`share` first, so that a
    cluster sends them to each worker once.
    """

    #: Tasks that can run at once.
    workers: int = 1
    #: Where the tasks run, in words (for messages and reports).
    where: str = ''

    def share(self, obj: Any) -> Any:
        """``obj`` as the tasks receive it (on a cluster: sent to every worker once)."""
        return obj

    def map(self, fn: Callable, items: Sequence, **shared) -> list:
        """``[fn(item, **shared) for item in items]``; the first task's exception raised."""
        raise NotImplementedError

    def stream(self, fn: Callable, items: Sequence, *, retries: int = 0,
               **shared) -> Iterator[tuple[int, Any]]:
        """``(index, result)`` of every task as it finishes; a task that raised gives its
        exception as the result (the batch goes on). ``retries``: times a task is run again
        when its worker is lost."""
        raise NotImplementedError

    def close(self) -> None:
        """Stop what this executor started."""

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


class InProcess(Executor):
    """Tasks in this process: one after the other with ``threads=1``, else on a pool of
    ``threads`` (worth it where the tasks release the GIL; see the module)."""

    def __init__(self, threads: int = 1):
        self.workers = max(1, int(threads))
        self.where = 'this process' + (f', {self.workers} threads' if self.workers > 1 else '')
        self._pool: ThreadPoolExecutor | None = None

    def _threads(self) -> ThreadPoolExecutor:
        if self._pool is None:
            self._pool = ThreadPoolExecutor(self.workers, thread_name_prefix='batch')
        return self._pool

    def map(self, fn, items, **shared):
        if self.workers == 1 or len(items) < 2:
            return [fn(x, **shared) for x in items]
        return list(self._threads().map(lambda x: fn(x, **shared), items))

    def stream(self, fn, items, *, retries=0, **shared):
        def one(x):
            try:
                return fn(x, **shared)
            except Exception as exc:  # noqa: BLE001 - handed to the caller as the result
                return exc
        if self.workers == 1 or len(items) < 2:
            for k, x in enumerate(items):
                yield k, one(x)
            return
        from concurrent.futures import as_completed
        futures = {self._threads().submit(one, x): k for k, x in enumerate(items)}
        for f in as_completed(futures):
            yield futures[f], f.result()

    def close(self):
        if self._pool is not None:
            # Tasks not started are dropped (the caller has stopped reading, e.g. on an
            # error); those running end first.
            self._pool.shutdown(cancel_futures=True)
            self._pool = None


class DaskExecutor(Executor):
    """Tasks on the workers of a Dask ``client``; ``cluster``: the local cluster this
    executor started and stops (None for a scheduler found by address, or a client the
    caller owns)."""

    def __init__(self, client, cluster=None, *, own_client: bool = False):
        self.client, self.cluster, self._own = client, cluster, own_client
        address = getattr(client, 'scheduler', None)
        address = getattr(address, 'address', '') or ''
        n = self.workers
        self.where = (f'a local Dask cluster ({n} worker{"s" * (n != 1)})' if cluster is not None
                      else f'the Dask scheduler at {address}')

    @property
    def workers(self) -> int:
        info = self.client.scheduler_info(n_workers=-1)
        return max(sum(w.get('nthreads', 1) for w in info.get('workers', {}).values()), 1)

    def share(self, obj):
        # In a list: Dask scatters a dict's values under the dict's own keys, which the
        # next batch's dict would reuse (its tasks then lose or mix their data). hash=False:
        # a key of its own, without tokenising a large object. One copy per worker.
        return self.client.scatter([obj], broadcast=True, hash=False)[0]

    def map(self, fn, items, **shared):
        if not items:
            return []
        futures = self.client.map(fn, list(items), pure=False, **shared)
        try:
            return self.client.gather(futures)
        finally:
            for f in futures:
                f.release()

    def stream(self, fn, items, *, retries=0, **shared):
        from dask.distributed import as_completed
        if not items:
            return
        futures = self.client.map(fn, list(items), pure=False, retries=retries or None,
                                  **shared)
        index = {f.key: k for k, f in enumerate(futures)}
        try:
            for fut in as_completed(futures, loop=self.client.loop):
                try:
                    res = fut.result()
                except Exception as exc:  # noqa: BLE001 - e.g. KilledWorker: the caller's
                    res = exc
                yield index[fut.key], res
                fut.release()
        finally:
            for f in futures:
                f.release()

    def close(self):
        if self._own:
            self.client.close()
        if self.cluster is not None:
            self.cluster.close()
            self.cluster = None


def open_client(address: str | None = None, workers: int | None = None):
    """A Dask client: to ``address`` (or ``DASK_SCHEDULER_ADDRESS``), else to a new local
    cluster of ``workers`` processes (default one per core). Returns ``(client, cluster)``;
    ``cluster`` is None for an external scheduler.

    Raises
    ------
    SchedulerError
        The scheduler cannot be reached within :data:`CONNECT_TIMEOUT`, or a local cluster
        of more than twice this machine's cores is asked for.
    """
    import dask
    from dask.distributed import Client, LocalCluster
    address = address or os.environ.get('DASK_SCHEDULER_ADDRESS') or None
    if address:
        try:
            return Client(address, timeout=CONNECT_TIMEOUT, set_as_default=False), None
        except Exception as exc:  # noqa: BLE001 - OSError, TimeoutError, ValueError (address)
            why = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
            raise SchedulerError(f'cannot reach the Dask scheduler at {address} within '
                                 f'{CONNECT_TIMEOUT:g} s ({why})') from None
    workers = workers or cores()
    if workers > 2 * cores():
        # A local cluster's workers are processes of this machine: more than two a core only
        # share the cores (and 1000 were spawned until the machine stopped them).
        raise SchedulerError(f'--workers {workers}: a local cluster of at most {2 * cores()} '
                             f'workers here (twice the {cores()} cores this process may use); '
                             'a cluster of more machines: --scheduler ADDRESS')
    # Two of Dask's worker defaults cost this suite's tasks time and buy nothing here: the
    # sampling profiler walks the running task's stack every 10 ms, and a fixed malloc trim
    # threshold makes glibc hand memory back after every large array of a task thread
    # (a calibration ran 10 % slower in a worker with it than in this process).
    with dask.config.set({'distributed.worker.profile.enabled': False,
                          TRIM: None}):
        # No dashboard; the scheduler's own HTTP server (health, metrics) on a free port of
        # this machine, not on 8787 of every interface, which another cluster may hold.
        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                               dashboard_address=None, silence_logs=logging.ERROR,
                               scheduler_kwargs={'dashboard_address': '127.0.0.1:0'})
    return Client(cluster, set_as_default=False), cluster


def open_executor(address: str | None = None, workers: int | None = None, *,
                  threads: int = 1) -> Executor:
    """An executor: the scheduler at ``address`` (or ``DASK_SCHEDULER_ADDRESS``); else with
    ``workers`` >= 1 a local cluster of that many processes; else (``workers`` 0 or None)
    this process with ``threads`` threads.

    Raises
    ------
    SchedulerError
        The scheduler cannot be reached within :data:`CONNECT_TIMEOUT`, or a local cluster
        of more than twice this machine's cores is asked for.
    """
    address = address or os.environ.get('DASK_SCHEDULER_ADDRESS') or None
    if address or workers:
        client, cluster = open_client(address, workers)
        return DaskExecutor(client, cluster, own_client=True)
    return InProcess(threads)
