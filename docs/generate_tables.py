"""Write the parameter tables of docs/ros.md and docs/parameters.md from the schemas, and the
benchmark table of bench/README.md from ``bench/results.json`` (what ``make bench``
measured).

    .venv/bin/python docs/generate_tables.py          # rewrite the tables in place
    .venv/bin/python docs/generate_tables.py --check  # exit 1 if a table is out of date

Each table sits between ``<!-- BEGIN params:NAME -->`` and ``<!-- END params:NAME -->``
(``<!-- BEGIN bench -->`` for the benchmarks); a test runs the check, so the tables cannot
drift from the schemas (the one place the defaults live) or from the measured figures.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
import re
import sys

from hydropump_ctrl.control.schema import ControllerConfig
from hydropump_ctrl.control.supervisor import ControllerNodeConfig
from hydropump_ctrl.recorder import RecorderConfig
from hydropump_sim.params import Params
from hydropump_sim.runner import SimulatorConfig
from hydropump_sim.schema import markdown_table, specs_of
from hydropump_sim.sensors import SensorConfig

ROOT = Path(__file__).resolve().parents[1]
TABLES = {
    'simulator': SimulatorConfig, 'controller': ControllerNodeConfig,
    'recorder': RecorderConfig, 'plant': Params, 'sensors': SensorConfig,
    'control': ControllerConfig,
}
FILES = (ROOT / 'docs' / 'ros.md', ROOT / 'docs' / 'parameters.md', ROOT / 'bench' / 'README.md')


def table(name: str) -> str:
    return markdown_table(specs_of(TABLES[name]), f'{name} parameter')


BENCH_RESULTS = ROOT / 'bench' / 'results.json'


def _value(v: float) -> str:
    return f'{v:.3g}' if isinstance(v, (int, float)) else str(v)


def bench_table() -> str:
    """The benchmark table of bench/README.md: every row ``bench/results.json`` holds, by
    benchmark, with its goal, whether it was met, and the run it comes from."""
    data = json.loads(BENCH_RESULTS.read_text()) if BENCH_RESULTS.exists() else {}
    out = ['| benchmark | figure | value | goal | note |', '| --- | --- | --- | --- | --- |']
    runs = []
    for bench, b in sorted(data.get('benchmarks', {}).items()):
        runs.append(f'{bench[6:]}: {b["run"]}')
        for r in b['rows']:
            ok = '' if r.get('ok') is None else (' (met)' if r['ok'] else ' (**missed**)')
            out.append(f'| {bench[6:]} | {r["name"]} | {_value(r["value"])} {r["unit"]} | '
                       f'{r.get("goal") or ""}{ok} | {r.get("note") or ""} |')
    machine = {b['machine'] for b in data.get('benchmarks', {}).values()}
    out += ['', f'Measured by `make bench` ({", ".join(sorted(machine))}); runs: '
            + '; '.join(runs) + '.']
    return '\n'.join(out)


def render(text: str) -> str:
    """``text`` with every marked table rewritten from its schema or the benchmarks."""
    def sub(m):
        return f'{m.group(1)}\n{table(m.group(2))}\n{m.group(3)}'
    text = re.sub(r'(<!-- BEGIN params:(\w+) -->)\n(?:.*?\n)?(<!-- END params:\2 -->)', sub,
                  text, flags=re.S)
    return re.sub(r'(<!-- BEGIN bench -->)\n(?:.*?\n)?(<!-- END bench -->)',
                  lambda m: f'{m.group(1)}\n{bench_table()}\n{m.group(2)}', text, flags=re.S)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--check', action='store_true', help='only check; exit 1 if out of date')
    args = ap.parse_args(argv)
    stale = []
    for path in FILES:
        text = path.read_text()
        new = render(text)
        if new != text:
            stale.append(path)
            if not args.check:
                path.write_text(new)
    if args.check and stale:
        print('out of date: ' + ', '.join(str(p.relative_to(ROOT)) for p in stale)
              + ' (run docs/generate_tables.py)', file=sys.stderr)
        return 1
    return 0


if __name__ == '__main__':
    sys.exit(main())
