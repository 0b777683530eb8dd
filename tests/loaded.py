"""Run a command with every core kept busy, as a shared machine keeps them: what ``make
soak`` runs the ROS and end-to-end tests under.

    python tests/loaded.py [--busy N] -- COMMAND...

``N`` busy processes (default: one per core) spin at normal priority for as long as the
command runs; they are ended by PID when it ends, however it ends. The exit code is the
command's.
"""

import argparse
import multiprocessing
import os
import signal
import subprocess
import sys


def _spin() -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)   # Ctrl-C is for the command
    x = 0
    while True:
        x = (x * 1103515245 + 12345) & 0xFFFFFFFF


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--busy', type=int, default=os.cpu_count() or 1,
                    help='busy processes (default: one per core)')
    ap.add_argument('command', nargs=argparse.REMAINDER)
    args = ap.parse_args(argv)
    cmd = args.command[1:] if args.command[:1] == ['--'] else args.command
    if not cmd:
        ap.error('give the command after --')
    ctx = multiprocessing.get_context('spawn')
    busy = [ctx.Process(target=_spin, daemon=True) for _ in range(max(args.busy, 0))]
    for p in busy:
        p.start()
    print(f'loaded: {len(busy)} busy processes ({", ".join(str(p.pid) for p in busy)})',
          file=sys.stderr, flush=True)
    try:
        return subprocess.call(cmd)
    finally:
        for p in busy:
            p.terminate()
        for p in busy:
            p.join(5)
            if p.is_alive():
                p.kill()


if __name__ == '__main__':
    sys.exit(main())
