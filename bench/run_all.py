"""Run every ``bench/bench_*.py`` in turn and print one table of figures and ratios."""

import json
from pathlib import Path
import subprocess
import sys

HERE = Path(__file__).resolve().parent


def main() -> int:
    rows, failed = [], []
    for script in sorted(HERE.glob('bench_*.py')):
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
    if failed:
        print(f'failed: {", ".join(failed)}', file=sys.stderr)
    return 1 if failed else 0


if __name__ == '__main__':
    sys.exit(main())
