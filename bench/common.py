"""Helpers shared by the benchmarks: medians of repeated timings and the result protocol.

Every benchmark prints its own readable lines, then one ``BENCH-RESULT <json>`` line with a list
of rows ``{name, value, unit, goal, ok, note}``; ``bench/run_all.py`` collects those rows into
one table. Speed figures are ratios against a baseline measured in the same run.
"""

import json
import os
import statistics
import time

os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')


def median_time(fn, repeat: int = 5) -> tuple[float, list[float]]:
    """Median wall time [s] of ``repeat`` calls of ``fn()``, and all the times."""
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), times


def row(name: str, value: float, unit: str, goal: str = '', ok: bool | None = None,
        note: str = '') -> dict:
    return {'name': name, 'value': value, 'unit': unit, 'goal': goal, 'ok': ok, 'note': note}


def emit(rows: list[dict]) -> None:
    for r in rows:
        flag = '' if r['ok'] is None else ('  ok' if r['ok'] else '  MISSED')
        print(f"  {r['name']:55s} {r['value']:>12.4g} {r['unit']:10s} {r['goal']}{flag}")
    print('BENCH-RESULT ' + json.dumps(rows), flush=True)
