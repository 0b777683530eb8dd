"""Node start-up: where the seconds go, from the process start to a node another process can
use, for each node started bare (as ``ros2 run`` does), against a bare rclpy node measured in
the same run.

Phases, each a median of REPEAT starts on an otherwise idle graph:
- ``imports``: importing the node's module (rclpy, numpy, scipy, numba, the suite);
- ``constructed``: up to the node's first log line (imports, rclpy init, parameter
  declaration, the compiled core loaded from numba's cache, the first equilibrium);
- ``ready``: up to its services being visible to another process (discovery included).

Usage: python bench/bench_startup.py [REPEAT]  (default 3)
"""

import os
from pathlib import Path
import random
import re
import signal
import statistics
import subprocess
import sys
import tempfile
import time

from common import emit, row

REPEAT = int(sys.argv[1]) if len(sys.argv) > 1 else 3
GOAL = 2.0  # s to ready, per node
NODES = {'simulator': ('hydropump_ros.simulator_node', '/simulator/reset'),
         'controller': ('hydropump_ros.controller_node', '/controller/get_state'),
         'recorder': ('hydropump_ros.recorder_node', '/recorder/ready')}
BASELINE = ('import rclpy\nfrom rclpy.node import Node\nfrom std_srvs.srv import Trigger\n'
            'rclpy.init()\nn = Node("baseline")\nn.get_logger().info("up")\n'
            'n.create_service(Trigger, "~/ready", lambda q, r: r)\nrclpy.spin(n)\n')
LOG_TIME = re.compile(r'\[(?:INFO|WARN)\] \[(\d+\.\d+)\]')


def executable(name: str) -> str:
    return str(Path(sys.prefix) / 'lib' / 'hydropump_ros' / name)


def import_time(module: str) -> float:
    code = f'import time; t = time.perf_counter(); import {module}; ' \
           'print(time.perf_counter() - t)'
    return float(subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                                check=True).stdout)


def start_once(node, cmd: list[str], service: str, log_dir: Path) -> tuple[float, float]:
    """(constructed, ready) [s] after the process start."""
    import rclpy
    log = log_dir / f'{random.randrange(10 ** 9)}.log'
    with open(log, 'w') as out:
        t0_wall, t0 = time.time(), time.perf_counter()
        proc = subprocess.Popen(cmd, stdout=out, stderr=subprocess.STDOUT)
        try:
            while not any(n == service for n, _ in node.get_service_names_and_types()):
                if proc.poll() is not None or time.perf_counter() - t0 > 60:
                    raise RuntimeError(f'{cmd[0]} did not start: {log.read_text()[-500:]}')
                rclpy.spin_once(node, timeout_sec=0.005)
            ready = time.perf_counter() - t0
        finally:
            proc.send_signal(signal.SIGINT)
            proc.wait(timeout=20)
    first = LOG_TIME.search(log.read_text())
    return (float(first.group(1)) - t0_wall if first else float('nan')), ready


def main() -> int:
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    os.environ['ROS_DOMAIN_ID'] = str(random.randrange(150, 200))
    import rclpy
    from rclpy.node import Node
    rclpy.init()
    probe = Node('startup_probe')
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        runs = {'baseline': [start_once(probe, [sys.executable, '-c', BASELINE],
                                        '/baseline/ready', Path(tmp)) for _ in range(REPEAT)]}
        for name, (_, service) in NODES.items():
            runs[name] = [start_once(probe, [executable(name)], service, Path(tmp))
                          for _ in range(REPEAT)]
    base = statistics.median(r[1] for r in runs['baseline'])
    print(f'{"node":12s} {"imports":>8s} {"constructed":>12s} {"ready":>8s}   [s, medians of '
          f'{REPEAT}]')
    for name, rs in runs.items():
        imp = import_time(NODES[name][0]) if name in NODES else import_time('rclpy')
        built, ready = (statistics.median(r[i] for r in rs) for i in (0, 1))
        print(f'{name:12s} {imp:8.2f} {built:12.2f} {ready:8.2f}')
        if name == 'baseline':
            rows.append(row('bare rclpy node: start to ready', ready, 's'))
            continue
        rows.append(row(f'{name}: start to ready', ready, 's', f'<= {GOAL:g} s', ready <= GOAL,
                        f'imports {imp:.2f} s, constructed {built:.2f} s, '
                        f'{ready / base:.1f}x the bare node'))
    probe.destroy_node()
    rclpy.try_shutdown()
    emit(rows)
    return 0


if __name__ == '__main__':
    sys.exit(main())
