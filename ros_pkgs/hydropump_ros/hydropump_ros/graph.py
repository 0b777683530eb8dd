"""``hydropump-graph``: start the node graph without ``ros2 launch`` (pip-only setups).

It does what ``hydropump_bringup/launch/closed_loop.launch.py`` does: simulator, controller and
recorder in one namespace, with the same arguments, as child processes. Ctrl-C (or SIGTERM)
stops them all; if one node exits, the others are stopped and its log is named.
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path
import signal
import subprocess
import sys
import time

from hydropump_sim.params import default_params_path

NODES = ('simulator', 'controller', 'recorder')


def node_command(node: str, namespace: str, ros_args: list[str]) -> list[str]:
    """Command line of one node: this Python, the node module, ``--ros-args``."""
    module = {'simulator': 'simulator_node', 'controller': 'controller_node',
              'recorder': 'recorder_node'}[node]
    cmd = [sys.executable, '-m', f'hydropump_ros.{module}', '--ros-args']
    if namespace:
        cmd += ['-r', f'__ns:={namespace if namespace.startswith("/") else "/" + namespace}']
    return cmd + ros_args


def graph_commands(args) -> dict[str, list[str]]:
    """The three command lines, as the launch file builds them."""
    plant = ['--params-file', str(args.params_file)]
    sim_args = list(plant)
    if args.sensor_profile:
        sim_args += ['--params-file', str(args.sensor_profile)]
    sim_args += ['-p', f'lock_step:={str(args.lock_step).lower()}',
                 '-p', f'real_time_factor:={args.real_time_factor}']
    sim_time = ['-p', f'use_sim_time:={str(args.use_sim_time).lower()}']
    ctrl_args = sim_time + ['-p', 'autostart:=true']
    if args.controller_params:
        ctrl_args += ['-p', f'config_file:={args.controller_params}']
    rec_args = sim_time + (['-p', f'output:={args.bag}'] if args.bag else [])
    cmds = {'simulator': node_command('simulator', args.namespace, sim_args),
            'controller': node_command('controller', args.namespace, ctrl_args),
            'recorder': node_command('recorder', args.namespace, rec_args)}
    return {k: v for k, v in cmds.items() if k not in (args.without or [])}


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog='hydropump-graph', description=__doc__.splitlines()[0])
    ap.add_argument('--namespace', default='', help='namespace of the suite (e.g. pump1)')
    ap.add_argument('--params-file', default=None, help='plant params (default config/pump.yaml)')
    ap.add_argument('--sensor-profile', default=None, help='e.g. config/bench.yaml')
    ap.add_argument('--controller-params', default=None, help='e.g. config/controller.yaml')
    ap.add_argument('--bag', default=None, help='bag directory of the recorder')
    ap.add_argument('--lock-step', action='store_true', help='simulator in lock-step mode')
    ap.add_argument('--real-time-factor', type=float, default=1.0, help='0 = as fast as possible')
    ap.add_argument('--no-sim-time', dest='use_sim_time', action='store_false',
                    help='controller and recorder on wall time')
    ap.add_argument('--without', action='append', choices=NODES, help='leave a node out')
    ap.add_argument('--log-dir', default=None, help="write each node's log to <dir>/<node>.log")
    return ap


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    args.params_file = args.params_file or default_params_path()
    for name in ('params_file', 'sensor_profile', 'controller_params'):
        value = getattr(args, name)
        if value and not Path(value).is_file():
            print(f'error: --{name.replace("_", "-")} {value}: no such file', file=sys.stderr)
            return 2
    env = dict(os.environ)
    env.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    procs, logs = {}, {}
    log_dir = Path(args.log_dir) if args.log_dir else None
    if log_dir:
        log_dir.mkdir(parents=True, exist_ok=True)
    for name, cmd in graph_commands(args).items():
        out = None
        if log_dir:
            logs[name] = log_dir / f'{name}.log'
            out = open(logs[name], 'w')  # noqa: SIM115 - closed when the child exits
        procs[name] = subprocess.Popen(cmd, env=env, stdout=out, stderr=subprocess.STDOUT
                                       if out else None)
        print(f'started {name} (pid {procs[name].pid})', flush=True)
    stopping = []

    def stop(*_):
        stopping.append(True)

    signal.signal(signal.SIGINT, stop)
    signal.signal(signal.SIGTERM, stop)
    rc = 0
    while not stopping:
        for name, p in procs.items():
            if p.poll() is not None:
                where = f'; see {logs[name]}' if name in logs else ''
                print(f'error: node {name} exited with code {p.returncode}{where}',
                      file=sys.stderr)
                rc = 1
                stopping.append(True)
                break
        time.sleep(0.2)
    for p in procs.values():
        if p.poll() is None:
            p.send_signal(signal.SIGTERM)
    for p in procs.values():
        try:
            p.wait(timeout=10)
        except subprocess.TimeoutExpired:
            p.kill()
    return rc


if __name__ == '__main__':
    sys.exit(main())
