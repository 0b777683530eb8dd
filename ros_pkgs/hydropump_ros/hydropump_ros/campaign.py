"""``hydropump-demo``: the paper end to end through the real node graph.

1. Identification campaign: nine open-loop experiments (growing-flow current staircases at
   differing operating points and noise seeds) through the simulator (bench sensor profile),
   the controller in ``open_loop`` mode and the recorder, in lock-step, into nine bags.
2. Fitting: eq. 19 on the nine bags (``hydropump fit``), next to the paper's figures and the
   plant's own (a noise-free, delay-free twin of each experiment, and the configured delay).
3. Closed loop: EMC and PI on a flow step, a load-aperture step and a margin set-point step.
4. Model analysis: the modal table and the singular-perturbation check.
5. Report: one self-contained HTML page with PNG figures in ``out/<timestamp>/``, the bags
   beside it.

Every node runs in its own process, logs to ``<run>/logs/<experiment>/<node>.log``, and is
ended by PID. A node that fails stops the run with a message that names it and its log.
"""

from __future__ import annotations

import argparse
import base64
from dataclasses import dataclass, field
from datetime import datetime
import html
import json
import math
import os
from pathlib import Path
import random
import signal
import subprocess
import sys
import time

import numpy as np

PAPER = {'G0': (100.0, 0.7), 'tau': (0.100, 0.002), 'td': (0.055, 0.0055)}
IDENT_TOPICS = ['solenoid_current', 'solenoid_current_cmd', 'line_flow', 'pump_flow',
                'joint_states', 'line_pressure', 'load_pressure']
LOOP_TOPICS = IDENT_TOPICS + ['load_flow', 'controller/state']
STAGES = ('identification', 'fitting', 'closed loop', 'model analysis', 'report')


class DemoError(Exception):
    """A failure that ends the run: one line for the user."""


# ---- experiments --------------------------------------------------------------------------

@dataclass
class Experiment:
    """One run of the graph: node arguments, topics to record, schedule of changes."""

    name: str
    label: str
    duration: float
    sim: dict
    ctrl: dict
    topics: list
    events: list = field(default_factory=list)   # (t, node, {param: value})
    scenario: dict | None = None                 # simulator scenario (inputs in sim time)


def identification_experiments(params, n: int = 9, dwell: float = 1.0, levels: int = 4
                               ) -> list[Experiment]:
    """Nine growing-flow staircases: three displacement ranges by three load pressures, each
    with its own noise seed (the paper: nine data sets, growing flow only)."""
    from hydropump_sim.scaling import current_for_displacement
    ranges = [(20.0, 50.0), (35.0, 65.0), (50.0, 80.0)]
    loads = [8.0e6, 1.2e7, 1.6e7]
    out = []
    for i in range(n):
        lo, hi = ranges[i % 3]
        pu = loads[(i // 3) % 3]
        out.append(Experiment(
            name=f'ident_{i + 1}',
            label=f'staircase {lo:.0f} -> {hi:.0f} %, P_u {pu / 1e5:.0f} bar, seed {i + 1}',
            duration=levels * dwell,
            sim={'initial_current': float(current_for_displacement(params, lo / 100.0)),
                 'line.P_u': pu, 'sensors.seed': i + 1},
            ctrl={'controller.mode': 'open_loop', 'excitation.signal': 'staircase',
                  'excitation.direction': 'up', 'excitation.unit': 'percent',
                  'excitation.levels_min': lo, 'excitation.levels_max': hi,
                  'excitation.n_levels': levels, 'excitation.dwell': dwell,
                  'excitation.repeat': False},
            topics=IDENT_TOPICS))
    return out


def closed_loop_experiments(params, algorithms=('emc', 'pi'), t_step: float = 0.5,
                            duration: float = 1.5) -> list[Experiment]:
    """The three judged scenarios for each algorithm: a 30 -> 70 % flow step, a load
    aperture step 0.5 -> 0.4 at a 25 bar margin, and a margin set-point step 20 -> 25 bar."""
    from hydropump_sim.scaling import current_for_displacement
    q30, q70 = 0.3 * params.Q_max, 0.7 * params.Q_max
    out = []
    for alg in algorithms:
        base = {'controller.algorithm': alg}
        out += [
            Experiment(f'{alg}_flow_step', f'{alg.upper()}: flow step 30 -> 70 %', duration,
                       {'initial_current': float(current_for_displacement(params, 0.3))},
                       {**base, 'controller.mode': 'flow', 'reference.flow': q30},
                       LOOP_TOPICS, [(t_step, 'controller', {'reference.flow': q70})]),
            Experiment(f'{alg}_aperture_step', f'{alg.upper()}: aperture 0.5 -> 0.4 at 25 bar',
                       duration, {}, {**base, 'controller.mode': 'margin',
                                      'reference.margin': 2.5e6},
                       LOOP_TOPICS, [], {'aperture': {'steps': [[0.0, 0.5], [t_step, 0.4]]}}),
            Experiment(f'{alg}_margin_step', f'{alg.upper()}: margin 20 -> 25 bar', duration,
                       {}, {**base, 'controller.mode': 'margin', 'reference.margin': 2.0e6},
                       LOOP_TOPICS, [(t_step, 'controller', {'reference.margin': 2.5e6})]),
        ]
    return out


# ---- the node graph -------------------------------------------------------------------------

def _executable(name: str) -> str:
    from ament_index_python.packages import get_package_prefix
    return str(Path(get_package_prefix('hydropump_ros')) / 'lib' / 'hydropump_ros' / name)


def _ros_value(v) -> str:
    if isinstance(v, bool):
        return 'true' if v else 'false'
    if isinstance(v, float):
        return repr(v)
    if isinstance(v, (list, tuple)):
        return '[' + ', '.join(str(x) for x in v) + ']'
    return str(v)


def _ros_args(values: dict) -> list[str]:
    out = []
    for k, v in values.items():
        out += ['-p', f'{k}:={_ros_value(v)}']
    return out


class Orchestrator:
    """The run's own rclpy node: service calls, parameter sets, the simulation clock."""

    def __init__(self):
        import rclpy
        from rclpy.node import Node
        from rosgraph_msgs.msg import Clock
        self.rclpy = rclpy
        rclpy.init()
        self.node = Node(f'hydropump_demo_{os.getpid()}')
        self.t = -1.0
        self.node.create_subscription(Clock, '/clock', self._on_clock, 100)
        self._clients = {}
        self.procs: dict = {}

    def _on_clock(self, msg) -> None:
        self.t = msg.clock.sec + msg.clock.nanosec * 1e-9

    def close(self) -> None:
        self.node.destroy_node()
        self.rclpy.try_shutdown()

    def check_nodes(self) -> None:
        for name, (proc, log, exp) in self.procs.items():
            if proc.poll() is not None:
                raise DemoError(f'node {name} of experiment {exp} exited with code '
                                f'{proc.returncode}: see {log}')

    def spin_until(self, predicate, timeout: float, what: str) -> None:
        deadline = time.monotonic() + timeout
        while not predicate():
            self.check_nodes()
            if time.monotonic() > deadline:
                raise DemoError(f'timed out after {timeout:g} s waiting for {what}')
            self.rclpy.spin_once(self.node, timeout_sec=0.01)

    def call(self, srv_type, name: str, request, timeout: float = 60.0):
        if name not in self._clients:
            self._clients[name] = self.node.create_client(srv_type, name)
        client = self._clients[name]
        self.spin_until(client.service_is_ready, timeout, f'the service {name}')
        future = client.call_async(request)
        self.spin_until(future.done, timeout, f'the answer of {name}')
        return future.result()

    def set_params(self, node: str, values: dict) -> None:
        from rcl_interfaces.srv import SetParameters
        from rclpy.parameter import Parameter
        req = SetParameters.Request(parameters=[Parameter(k, value=v).to_parameter_msg()
                                                for k, v in values.items()])
        for name, result in zip(values, self.call(SetParameters, f'{node}/set_parameters',
                                                  req).results):
            if not result.successful:
                raise DemoError(f'{node} refused {name} = {values[name]}: {result.reason}')


def run_experiment(orch: Orchestrator, exp: Experiment, run_dir: Path, bag_dir: Path,
                   sensor_profile: Path) -> Path:
    """Start the three nodes, run the experiment in lock-step, stop, return the bag."""
    from lifecycle_msgs.msg import State
    from lifecycle_msgs.srv import GetState
    from std_srvs.srv import SetBool, Trigger
    logs = run_dir / 'logs' / exp.name
    logs.mkdir(parents=True, exist_ok=True)
    bag = bag_dir / exp.name
    sim = {'lock_step': True, 'lock_step_timeout': 60.0, 'start_paused': True,
           'command_timeout': 60.0, **exp.sim}
    if exp.scenario:
        import yaml
        sc = logs / 'scenario.yaml'
        sc.write_text(yaml.safe_dump({'duration': exp.duration, 'inputs': exp.scenario}))
        sim['scenario_file'] = str(sc)
    commands = {
        'recorder': ['-p', 'use_sim_time:=true', '-p', f'output:={bag}',
                     '-p', f'topics:={_ros_value(exp.topics)}'],
        'simulator': ['--params-file', str(sensor_profile)] + _ros_args(sim),
        'controller': ['-p', 'use_sim_time:=true', '-p', 'autostart:=true',
                       '-p', 'watchdog.hold_timeout:=30.0', '-p', 'watchdog.safe_timeout:=60.0']
        + _ros_args(exp.ctrl),
    }
    orch.procs = {}
    orch.t = -1.0  # this experiment's clock only
    try:
        for name in ('recorder', 'simulator', 'controller'):
            log = logs / f'{name}.log'
            proc = subprocess.Popen([_executable(name), '--ros-args'] + commands[name],
                                    stdout=open(log, 'w'), stderr=subprocess.STDOUT)
            orch.procs[name] = (proc, log, exp.name)
        get_state = GetState.Request()
        orch.spin_until(lambda: orch.call(GetState, 'controller/get_state', get_state)
                        .current_state.id == State.PRIMARY_STATE_ACTIVE, 60,
                        'the controller to be active')
        orch.spin_until(lambda: orch.call(Trigger, 'recorder/ready', Trigger.Request()).success,
                        60, 'the recorder to match every topic')
        # Run through the schedule: pause at each change, apply it, go on.
        for t, node, values in sorted(exp.events, key=lambda e: e[0]) + [
                (exp.duration, None, None)]:
            orch.set_params('simulator', {'pause_at': float(t)})
            orch.call(SetBool, 'simulator/pause', SetBool.Request(data=False))
            orch.spin_until(lambda t=t: orch.t >= t - 1e-9, 600,
                            f'simulation time {t:g} s of {exp.name}')
            if node:
                orch.set_params(node, values)
        if not orch.call(Trigger, 'recorder/stop', Trigger.Request(), timeout=120).success:
            raise DemoError(f'the recorder of {exp.name} did not close its bag: see '
                            f'{logs / "recorder.log"}')
    finally:
        for proc, _, _ in orch.procs.values():
            if proc.poll() is None:
                proc.send_signal(signal.SIGTERM)
        for proc, _, _ in orch.procs.values():
            try:
                proc.wait(timeout=20)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        orch.procs = {}
    return bag


# ---- analysis of the runs -----------------------------------------------------------------

def plant_truth(params, profile, bags, ident) -> dict:
    """The plant's own eq. 19 under the bench conditions: each experiment replayed on the fine
    model with the commanded current, dither on, no sensor delay or noise, and fitted.

    The commanded current comes from the recordings the fit read (``ident.recordings``, one
    per bag): the bags are decoded once."""
    from hydropump_ctrl.ident import fit_recordings, Recording
    from hydropump_sim import simulate
    plant = params.replace(profile.plant_overrides or {})
    recs = []
    for bag, rec in zip(bags, ident.recordings):
        # The command starts with the controller's first update; time from there, in the
        # grid's whole nanoseconds.
        ok = np.isfinite(rec['solenoid_current_cmd'])
        ns = np.round(rec.t[ok] * 1e9).astype(np.int64)
        t, u = (ns - ns[0]) * 1e-9, rec['solenoid_current_cmd'][ok]

        def held(tt, t=t, u=u):
            return u[np.clip(np.searchsorted(t, tt, side='right') - 1, 0, u.size - 1)]

        res = simulate(plant, float(t[-1]) + 1e-3, held, dt_out=1e-3)
        recs.append(Recording(res.t, {'solenoid_current': held(res.t), 'line_flow': res.q_l},
                              name=f'{Path(bag).name} twin'))
    twin = fit_recordings(recs, params=params, joint=False)
    return {'G0': twin.G0, 'tau': twin.tau, 'td_plant': twin.td,
            'td_configured': profile.spec('line_flow').delay,
            'tau_nominal': _nominal_tau(params)}


def _nominal_tau(params) -> float:
    """63 % time of the fine model's own 40 -> 60 % up-step, no dither (100.4 ms in
    docs/reference.md)."""
    from hydropump_sim import equilibrium, simulate
    from hydropump_sim.metrics import step_figures
    from hydropump_sim.scaling import current_for_displacement
    I0, I1 = current_for_displacement(params, [0.4, 0.6])
    r = simulate(params, 1.2, lambda t: np.where(t < 0.01, I0, I1), dt_out=1e-4)
    return step_figures(r.t, r.q_l, 0.01, final=equilibrium(params, I1).q_l).t63


def _bag_arrays(bag: Path):
    """Times [s of simulation] and values of the closed-loop signals of a bag, on the grid of
    its recording."""
    from hydropump_ctrl.ident import read_recording
    rec = read_recording(bag)
    t = rec.t + rec.t0_ns * 1e-9
    keys = {'js': 'actuator_position', 'lp': 'line_pressure', 'up': 'load_pressure',
            'cmd': 'solenoid_current_cmd', 'state': 'controller_reference'}
    return {k: (t, rec[sig]) for k, sig in keys.items() if sig in rec}


def _average(t, x, width: float):
    """Centred moving average over ``width`` seconds, where a whole window fits."""
    from hydropump_sim.metrics import moving_average
    k = max(1, int(round(width / float(np.median(np.diff(t))))))
    y = moving_average(x, k, edges='valid')
    return t[k // 2:k // 2 + y.size], y


def loop_figures(params, exp: Experiment, bag: Path, t_step: float = 0.5) -> dict:
    """Rise, overshoot, settling and IAE of one closed-loop run (true flow or measured margin,
    averaged over one dither period / 20 ms as the paper filters the dither)."""
    from hydropump_sim.metrics import step_figures
    d = _bag_arrays(bag)
    if exp.ctrl['controller.mode'] == 'flow':
        t, x_a = d['js']
        q = params.Q_max * (0.5 + x_a / params.pump.x_a_max)
        t, y = _average(t, q, 1.0 / params.input.dither_freq)
        y0, y1 = exp.ctrl['reference.flow'], exp.events[0][2]['reference.flow']
        scale, unit, band = 100.0 / params.Q_max, '% FS', 0.02 * abs(y1 - y0)
    else:
        t, pl = d['lp']
        tu, pu = d['up']
        n = min(t.size, tu.size)
        t, y = _average(t[:n], pl[:n] - pu[:n], 0.02)
        y0 = exp.ctrl['reference.margin']
        y1 = exp.events[0][2]['reference.margin'] if exp.events else y0
        scale, unit, band = 1e-5, 'bar', 0.5e5
    sel = t >= t_step - 0.1
    t, y = t[sel], y[sel]
    if y1 != y0:
        f = step_figures(t, y, t_step, initial=y0, final=y1, band_abs=band)
        return {'rise_s': f.rise, 'overshoot_pct': f.overshoot, 'settling_s': f.settling,
                'iae': f.iae * scale, 'iae_unit': f'{unit} s', 'y': (t, y * scale),
                'unit': unit}
    # Disturbance: the peak deviation and the recovery to within 1 bar of the set-point.
    err = y - y0
    after = t >= t_step
    peak = float(np.max(np.abs(err[after])))
    outside = np.flatnonzero(np.abs(err[after]) > 1e5)
    rec = float(t[after][outside[-1] + 1] - t_step) if outside.size and outside[-1] + 1 < \
        after.sum() else (0.0 if not outside.size else math.inf)
    iae = float(np.trapezoid(np.abs(err[after]), t[after]))
    return {'peak_bar': peak * 1e-5, 'recovery_s': rec, 'iae': iae * 1e-5,
            'iae_unit': 'bar s', 'y': (t, y * 1e-5), 'unit': 'bar'}


# ---- figures --------------------------------------------------------------------------------

def _plt():
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    return plt


def plot_bode_identified(params, ident, path: Path) -> None:
    """Current to line flow: fine (growing flow), simplified and the identified eq. 19."""
    import control

    from hydropump_sim import equilibrium, linearize
    from hydropump_sim.linear import bode_data
    plt = _plt()
    w = np.logspace(-0.5, 3.5, 400)
    norm = 100.0 * (params.current_range[1] - params.current_range[0]) / params.Q_max
    fig, (am, ap) = plt.subplots(2, 1, figsize=(8, 6.2), sharex=True)
    for name, model in (('fine model (x_c > 0)', 'fine'), ('simplified (K_c kept)',
                                                            'simplified_Kc')):
        ss = linearize(params, equilibrium(params, model=model), 'pos', model).ss(
            inputs=['i_s'], outputs=['q_l'])
        mag, ph = bode_data(ss, w)
        am.semilogx(w / (2 * np.pi), 20 * np.log10(mag * norm), label=name)
        ap.semilogx(w / (2 * np.pi), ph)
    G = control.tf([ident.G0], [ident.tau, 1.0])
    mag, ph = bode_data(G, w)
    ph = ph - np.degrees(w * ident.td)
    am.semilogx(w / (2 * np.pi), 20 * np.log10(mag), 'k--',
                label=f'identified eq. 19 (incl. t_d = {ident.td * 1e3:.1f} ms)')
    ap.semilogx(w / (2 * np.pi), ph, 'k--')
    am.set_ylabel('|q_l / I_s| [dB, % per current range]')
    ap.set_ylabel('phase [deg]')
    ap.set_ylim(-400, 10)
    ap.set_xlabel('frequency [Hz]')
    am.legend(fontsize=8)
    for ax in (am, ap):
        ax.grid(True, which='both', alpha=0.3)
    am.set_title('Fine vs simplified vs identified (growing flow)')
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def plot_hysteresis(params, path: Path, levels: int = 13, hold: float = 1.5) -> dict:
    """The quasi-static current-flow loop: a staircase 20 -> 80 -> 20 % held ``hold`` s per
    level, with Coulomb friction (0.5 N spool, 20 N plate) and without. Each point is the mean
    flow over the last third of its hold, shown as the deviation from the static map of
    eq. 11, where the loop is visible. Returns the gap at mid range (up minus down, % FS)."""
    from hydropump_sim import simulate
    from hydropump_sim.scaling import (
        current_for_displacement,
        displacement_of_current,
        flow_percent,
    )
    plt = _plt()
    d = np.linspace(0.2, 0.8, levels)
    seq = np.concatenate([d, d[-2::-1]])
    currents = current_for_displacement(params, seq)

    def stairs(t):
        return currents[np.minimum((np.asarray(t) // hold).astype(int), seq.size - 1)]

    out = {}
    fig, ax = plt.subplots(figsize=(7, 5))
    for label, p, style in (('no friction', params, 'o-'),
                            ('Coulomb 0.5 N spool, 20 N plate', params.replace(
                                {'spool.F_coul_c': 0.5, 'plate.F_coul_a': 20.0}), 's-')):
        r = simulate(p, hold * seq.size, stairs, dt_out=5e-3)
        k = np.arange(seq.size)
        sel = [(r.t >= (i + 2 / 3) * hold) & (r.t < (i + 1) * hold) for i in k]
        q = np.array([np.mean(flow_percent(params, r.q_l[m])) for m in sel])
        dev = q - 100.0 * displacement_of_current(params, currents)
        ax.plot(currents, dev, style, label=label, ms=4)
        mid = levels // 2
        out[label] = float(dev[mid] - dev[seq.size - 1 - mid])
    ax.axhline(0.0, color='grey', lw=0.8)
    ax.set_xlabel('solenoid current I_s [A]')
    ax.set_ylabel('settled q_l minus eq. 11 [% of V_p f_p]')
    ax.set_title(f'Current-flow hysteresis (staircase 20 -> 80 -> 20 %, {hold:g} s per level)')
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return out


def plot_closed_loop(results: dict, path: Path) -> None:
    """EMC against PI on the three scenarios."""
    plt = _plt()
    scen = ['flow_step', 'aperture_step', 'margin_step']
    titles = {'flow_step': 'flow step 30 -> 70 %', 'aperture_step':
              'aperture 0.5 -> 0.4 (margin 25 bar)', 'margin_step': 'margin 20 -> 25 bar'}
    fig, axes = plt.subplots(1, 3, figsize=(14, 4))
    for ax, s in zip(axes, scen):
        for alg, style in (('emc', 'tab:blue'), ('pi', 'tab:orange')):
            f = results.get(f'{alg}_{s}')
            if f:
                t, y = f['y']
                ax.plot(t, y, color=style, label=alg.upper())
        ax.set_title(titles[s])
        ax.set_xlabel('simulation time [s]')
        unit = next((results[k]['unit'] for k in results if k.endswith(s)), '')
        ax.set_ylabel('flow [% FS]' if unit == '% FS' else 'margin P_l - P_u [bar]')
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle('EMC against the PI baseline, real nodes, bench sensors (lock-step)')
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


# ---- report ---------------------------------------------------------------------------------

def _img(path: Path) -> str:
    data = base64.b64encode(path.read_bytes()).decode()
    return (f'<figure><img src="data:image/png;base64,{data}" alt="{path.name}">'
            f'<figcaption>{html.escape(path.name)}</figcaption></figure>')


def _table(head, rows) -> str:
    h = ''.join(f'<th>{html.escape(str(x))}</th>' for x in head)
    body = ''.join('<tr>' + ''.join(f'<td>{html.escape(str(x))}</td>' for x in r) + '</tr>'
                   for r in rows)
    return f'<table><tr>{h}</tr>{body}</table>'


def write_html(run_dir: Path, sections: list[tuple[str, str]]) -> Path:
    css = ('body{font-family:sans-serif;max-width:1200px;margin:auto;padding:1em}'
           'table{border-collapse:collapse;margin:1em 0}td,th{border:1px solid #bbb;'
           'padding:3px 8px;text-align:right}th{background:#eee}img{max-width:100%}'
           'pre{background:#f6f6f6;padding:.6em;overflow-x:auto;font-size:12px}')
    parts = [f'<!doctype html><html><head><meta charset="utf-8"><title>hydropump report</title>'
             f'<style>{css}</style></head><body><h1>hydropump: the paper end to end</h1>']
    for title, body in sections:
        parts.append(f'<h2>{html.escape(title)}</h2>{body}')
    parts.append('</body></html>')
    path = run_dir / 'report.html'
    path.write_text('\n'.join(parts))
    return path


# ---- the run --------------------------------------------------------------------------------

def _progress(msg: str) -> None:
    print(msg, flush=True)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog='hydropump-demo', description=__doc__.splitlines()[0])
    ap.add_argument('--out', help='run folder (default: out/<timestamp>)')
    ap.add_argument('--quick', action='store_true',
                    help='a short campaign: three identification experiments, EMC only')
    ap.add_argument('--sets', type=int, default=None, help='identification experiments')
    ap.add_argument('--dwell', type=float, default=None, help='stair duration [s]')
    args = ap.parse_args(argv)
    try:
        return run(args)
    except DemoError as exc:
        print(f'error: {exc}', file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print('interrupted', file=sys.stderr)
        return 130


def run(args) -> int:
    from domain_coordinator import domain_id

    from hydropump_sim.params import default_params_path, load_params, ParamError
    from hydropump_sim.sensors import load_profile
    t_all = time.perf_counter()
    run_dir = Path(args.out) if args.out else Path('out') / datetime.now().strftime(
        '%Y%m%d-%H%M%S')
    run_dir.mkdir(parents=True, exist_ok=True)
    bag_dir = run_dir / 'bags'
    try:
        params = load_params(default_params_path())
        profile_path = default_params_path().with_name('bench.yaml')
        profile = load_profile(profile_path)
    except ParamError as exc:
        raise DemoError('; '.join(exc.lines)) from None
    n_sets = args.sets or (3 if args.quick else 9)
    dwell = args.dwell or (0.6 if args.quick else 1.0)
    idents = identification_experiments(params, n_sets, dwell)
    loops = closed_loop_experiments(params, ('emc',) if args.quick else ('emc', 'pi'))
    walls = {}
    _progress(f'run folder: {run_dir}')
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    start = random.randrange(100)
    with domain_id(lambda s=[start]: (s.__setitem__(0, s[0] + 1) or s[0] % 100 + 1)) as did:
        os.environ['ROS_DOMAIN_ID'] = str(did)
        orch = Orchestrator()
        try:
            # 1. Identification campaign.
            t0 = time.perf_counter()
            bags = []
            for i, exp in enumerate(idents, 1):
                t1 = time.perf_counter()
                _progress(f'[1/5 identification {i}/{len(idents)}] {exp.label} ...')
                bags.append(run_experiment(orch, exp, run_dir, bag_dir, profile_path))
                _progress(f'      {exp.duration:g} s simulated in '
                          f'{time.perf_counter() - t1:.1f} s -> {bags[-1]}')
            walls['identification'] = time.perf_counter() - t0
            # 3. Closed loop (runs here, while the graph tools are up; reported after fitting).
            t0 = time.perf_counter()
            loop_bags = {}
            for i, exp in enumerate(loops, 1):
                t1 = time.perf_counter()
                _progress(f'[3/5 closed loop {i}/{len(loops)}] {exp.label} ...')
                loop_bags[exp.name] = run_experiment(orch, exp, run_dir, bag_dir, profile_path)
                _progress(f'      {exp.duration:g} s simulated in '
                          f'{time.perf_counter() - t1:.1f} s')
            walls['closed loop'] = time.perf_counter() - t0
        finally:
            orch.close()
    # 2. Fitting.
    t0 = time.perf_counter()
    _progress('[2/5 fitting] eq. 19 on the identification bags ...')
    from hydropump_ctrl.ident import fit_bags, format_table, write_report
    ident = fit_bags(bags, params=params, progress=None)
    fit_paths = write_report(ident, run_dir / 'identification', params=params)
    truth = plant_truth(params, profile, bags, ident)
    walls['fitting'] = time.perf_counter() - t0
    print(format_table(ident))
    rows = identification_rows(ident, truth)
    print(_text_table(['', 'G0 [%/range]', 'tau [ms]', 't_d [ms]'], rows))
    loop_results = {name: loop_figures(params, exp, loop_bags[exp.name])
                    for name, exp in ((e.name, e) for e in loops)}
    print(_text_table(*loop_table(loop_results)))
    # 4. Model analysis.
    t0 = time.perf_counter()
    _progress('[4/5 model analysis] modes and the singular-perturbation check ...')
    from hydropump_sim import analysis
    text, steps = analysis.format_report(params)
    modal = text[text.index('== Fine-model modes'):text.index('== Paper linear models')]
    print(modal)
    walls['model analysis'] = time.perf_counter() - t0
    # 5. Report.
    t0 = time.perf_counter()
    _progress('[5/5 report] figures and report.html ...')
    figs = run_dir / 'figures'
    figs.mkdir(exist_ok=True)
    analysis.plot_steps(steps, params, figs / 'steps.png')
    plot_bode_identified(params, ident, figs / 'bode.png')
    hyst = plot_hysteresis(params, figs / 'hysteresis.png')
    plot_closed_loop(loop_results, figs / 'emc_vs_pi.png')
    walls['report'] = time.perf_counter() - t0
    walls['total'] = time.perf_counter() - t_all
    sections = report_sections(ident, truth, rows, loop_results, modal, text, hyst, walls,
                               fit_paths, figs, bag_dir)
    page = write_html(run_dir, sections)
    (run_dir / 'summary.json').write_text(json.dumps(summary(ident, truth, loop_results,
                                                             walls), indent=2) + '\n')
    print(_text_table(['stage', 'wall time [s]'], [[k, f'{v:.1f}'] for k, v in
                                                   walls.items()]))
    print(f'\nreport: {page.resolve()}\nbags: {bag_dir.resolve()}')
    return 0


def identification_rows(ident, truth) -> list[list[str]]:
    p = ident.pooled

    def pm(m, s, k=1.0, f='.1f'):
        return f'{m * k:{f}} ± {s * k:{f}}'
    return [
        ['paper (9 sets)', pm(*PAPER['G0']), pm(*PAPER['tau'], 1e3), pm(*PAPER['td'], 1e3)],
        [f'this run ({len(ident.sets)} sets, mean ± std)', pm(p.mean['G0'], p.std['G0'], 1,
                                                             '.2f'),
         pm(p.mean['tau'], p.std['tau'], 1e3), pm(p.mean['td'], p.std['td'], 1e3)],
        ['plant: fine model + bench dither, no sensors', f'{truth["G0"]:.2f}',
         f'{truth["tau"] * 1e3:.1f}', f'{truth["td_plant"] * 1e3:.2f}'],
        ['plant: configured sensor delay', '', '', f'{truth["td_configured"] * 1e3:.1f}'],
        ['plant: fine model 63 % time, no dither', '', f'{truth["tau_nominal"] * 1e3:.1f}',
         ''],
    ]


def loop_table(results: dict):
    head = ['run', 'rise [s]', 'overshoot [%]', 'settling [s]', 'peak dev. [bar]',
            'recovery [s]', 'IAE']
    rows = []
    for name, f in results.items():
        rows.append([name, _fmt(f.get('rise_s')), _fmt(f.get('overshoot_pct')),
                     _fmt(f.get('settling_s')), _fmt(f.get('peak_bar')),
                     _fmt(f.get('recovery_s')), f'{f["iae"]:.4g} {f["iae_unit"]}'])
    return head, rows


def _fmt(v) -> str:
    return '' if v is None else ('never' if v == math.inf else f'{v:.3g}')


def _text_table(head, rows) -> str:
    cols = [head] + rows
    w = [max(len(str(r[i])) for r in cols) for i in range(len(head))]
    line = lambda r: '  '.join(str(x).ljust(w[i]) for i, x in enumerate(r))  # noqa: E731
    return '\n'.join([line(head), line(['-' * x for x in w])] + [line(r) for r in rows])


def report_sections(ident, truth, rows, loops, modal, analysis_text, hyst, walls, fit_paths,
                    figs, bag_dir):
    head, lrows = loop_table(loops)
    return [
        ('Identification (section V, eq. 19): the paper against this run',
         _table(['', 'G0 [% per range]', 'tau [ms]', 't_d [ms]'], rows)
         + '<p>Nine growing-flow current staircases through the real nodes (simulator with '
           'the bench sensor profile, controller in open loop, recorder), fitted with the '
           'robust method. The plant rows show what a perfect fit should find: the fine '
           'model under the same dither without sensors, and the configured delay.</p>'
         + _img(Path(fit_paths['fig5'])) + _img(Path(fit_paths['fig6']))),
        ('Bode: fine vs simplified vs identified', _img(figs / 'bode.png')),
        ('Step responses up and down', _img(figs / 'steps.png')),
        ('Current-flow hysteresis with friction', _table(
            ['model', 'settled q_l, from below minus from above, at 50 % [% FS]'],
            [[k, f'{v:.3f}'] for k, v in hyst.items()]) + _img(figs / 'hysteresis.png')),
        ('EMC against PI (closed loop through the nodes)', _table(head, lrows)
         + _img(figs / 'emc_vs_pi.png')),
        ('Model analysis (section IV)', f'<pre>{html.escape(modal)}</pre>'
         f'<details><summary>full analysis</summary><pre>{html.escape(analysis_text)}'
         f'</pre></details>'),
        ('Run', _table(['stage', 'wall time [s]'], [[k, f'{v:.1f}'] for k, v in walls.items()])
         + f'<p>Bags (rosbag2, MCAP): <code>{html.escape(str(bag_dir.resolve()))}</code>; '
           '<code>ros2 bag info</code> and <code>ros2 bag play</code> read them.</p>'),
    ]


def summary(ident, truth, loops, walls) -> dict:
    p = ident.pooled
    return {'identification': {'G0': p.mean['G0'], 'G0_std': p.std['G0'],
                               'tau': p.mean['tau'], 'tau_std': p.std['tau'],
                               'td': p.mean['td'], 'td_std': p.std['td'],
                               'sets': len(ident.sets)},
            'plant': truth,
            'closed_loop': {k: {kk: vv for kk, vv in v.items() if kk != 'y'}
                            for k, v in loops.items()},
            'wall_time_s': walls}


if __name__ == '__main__':
    sys.exit(main())
