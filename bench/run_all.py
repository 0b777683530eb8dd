"""Run every ``bench/bench_*.py`` in turn, print one table of figures and ratios, and write
them to ``bench/results.json``, from which ``docs/generate_tables.py`` writes the
benchmark table (so no figure there is one no command produced).

    .venv/bin/python bench/run_all.py [bench_calibrate ...]   # all, or the ones named
"""

from datetime import datetime, UTC
import json
import os
from pathlib import Path
import platform
import subprocess
import sys

HERE = Path(__file__).resolve().parent
RESULTS = HERE / 'results.json'


def main(argv=None) -> int:
    only = set(sys.argv[1:] if argv is None else argv)
    rows, failed = [], []
    old = json.loads(RESULTS.read_text()) if RESULTS.exists() else {'benchmarks': {}}
    for script in sorted(HERE.glob('bench_*.py')):
        if only and script.stem not in only:
            continue
        print(f'== {script.name}', flush=True)
        proc = subprocess.run([sys.executable, str(script)], capture_output=True, text=True)
        found = False
        for line in proc.stdout.splitlines():
            if line.startswith('BENCH-RESULT '):
                rows += [dict(r, bench=script.stem) for r in json.loads(line[13:])]
                found = True
            else:
                print('   ' + line)
        if proc.returncode != 0 or not found:
            failed.append(script.name)
            print(proc.stderr[-2000:], file=sys.stderr)
    print('\n== Summary')
    print(f"{'benchmark':18s} {'figure':55s} {'value':>12s} {'unit':10s} goal")
    for r in rows:
        flag = '' if r['ok'] is None else (' ok' if r['ok'] else ' MISSED')
        print(f"{r['bench'][6:]:18s} {r['name']:55s} {r['value']:>12.4g} {r['unit']:10s} "
              f"{r['goal']}{flag}")
    # A benchmark run alone replaces its own rows; the others keep theirs (and their date).
    when = datetime.now(UTC).strftime('%Y-%m-%d %H:%M UTC')
    machine = f'{os.cpu_count()} cores, {platform.system()} {platform.machine()}, Python ' \
              f'{platform.python_version()}'
    for bench in sorted({r['bench'] for r in rows}):
        old['benchmarks'][bench] = {'run': when, 'machine': machine,
                                    'rows': [{k: v for k, v in r.items() if k != 'bench'}
                                             for r in rows if r['bench'] == bench]}
    RESULTS.write_text(json.dumps(old, indent=1) + '\n')
    print(f'wrote {RESULTS.relative_to(HERE.parent)}; the table of bench/README.md: '
          'docs/generate_tables.py')
    if failed:
        print(f'failed: {", ".join(failed)}', file=sys.stderr)
    return 1 if failed else 0


if __name__ == '__main__':
    sys.exit(main())
