"""ROS layer benchmarks over real DDS (localhost, a reserved domain), each against a baseline
measured in the same run:

- real-time mode: all topics at 1 kHz for DURATION s at real-time factor 1; p99 step-period
  error (simulator's own measure) and the rate a subscriber sees;
- free run: the real-time factor reached at real_time_factor 0;
- lock-step: control periods per second against a bare rclpy ping-pong between two processes;
- recorder: messages recorded against messages published, full topic set at 1 kHz.

Usage: python bench/bench_ros.py [DURATION_S]  (default 60)
"""

import os
from pathlib import Path
import random
import signal
import subprocess
import sys
import tempfile
import textwrap
import time

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import emit, row  # noqa: E402

DURATION = float(sys.argv[1]) if len(sys.argv) > 1 else 60.0
SUITE = ['solenoid_current', 'pump_flow', 'line_flow', 'load_flow', 'actuator_pressure',
         'line_pressure', 'load_pressure', 'joint_states']

PROBE = textwrap.dedent("""
    import sys, time, rclpy
    from rclpy.node import Node
    from rclpy.qos import QoSProfile, ReliabilityPolicy, HistoryPolicy
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import JointState
    from diagnostic_msgs.msg import DiagnosticArray
    rclpy.init()
    n = Node('bench_probe')
    qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE,
                     history=HistoryPolicy.KEEP_LAST)
    js, clock, diag = [], [], []
    light = len(sys.argv) > 2  # sim time from /diagnostics only: no per-step load
    if not light:
        n.create_subscription(JointState, 'joint_states', lambda m: js.append(
            time.monotonic()), qos)
        n.create_subscription(Clock, '/clock', lambda m: clock.append(
            (time.monotonic(), m.clock.sec + m.clock.nanosec * 1e-9)), qos)
    def on_diag(m):
        diag.append(m)
        for s in m.status:
            for kv in s.values:
                if kv.key == 'sim_time_s':
                    clock.append((time.monotonic(), float(kv.value)))
    n.create_subscription(DiagnosticArray, '/diagnostics', on_diag if light else diag.append,
                          10)
    end = time.monotonic() + float(sys.argv[1])
    while time.monotonic() < end:
        rclpy.spin_once(n, timeout_sec=0.05)
    w = [t for t in js if t > js[0] + 2.0] if js else []
    rate = (len(w) - 1) / (w[-1] - w[0]) if len(w) > 1 else 0.0
    c = [x for x in clock if x[0] > clock[0][0] + 2.0] if clock else []
    rtf = (c[-1][1] - c[0][1]) / (c[-1][0] - c[0][0]) if len(c) > 1 else 0.0
    vals = {kv.key: kv.value for s in diag[-1].status for kv in s.values} if diag else {}
    print('RESULT', rate, rtf, vals.get('step_period_error_p99_s', 'nan'),
          vals.get('achieved_real_time_factor', 'nan'))
""")

RESPONDER = textwrap.dedent("""
    import sys, time, rclpy
    from rclpy.node import Node
    from rclpy.qos import QoSProfile, ReliabilityPolicy, HistoryPolicy
    from rosgraph_msgs.msg import Clock
    from std_msgs.msg import Float64
    rclpy.init()
    n = Node('bench_responder')
    pub = n.create_publisher(Float64, 'solenoid_current_cmd', 10)
    seen = [-1]
    period = int(round(float(sys.argv[1]) * 1e9))
    def on_clock(m):
        ns = m.clock.sec * 10**9 + m.clock.nanosec
        if ns % period == 0 and ns // period > seen[0]:
            seen[0] = ns // period
            pub.publish(Float64(data=0.5))
    n.create_subscription(Clock, '/clock', on_clock, QoSProfile(
        depth=1000, reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST))
    t0 = time.monotonic()
    while rclpy.ok():
        rclpy.spin_once(n, timeout_sec=0.1)
        if seen[0] < 0 and time.monotonic() - t0 > 3.0:
            seen[0] = 0
            pub.publish(Float64(data=0.5))
""")

PINGPONG = textwrap.dedent("""
    import sys, time, rclpy
    from rclpy.node import Node
    from std_msgs.msg import Float64
    rclpy.init()
    role = sys.argv[1]
    n = Node('bench_' + role)
    if role == 'pong':
        pub = n.create_publisher(Float64, 'pong', 10)
        n.create_subscription(Float64, 'ping', lambda m: pub.publish(m), 10)
        while rclpy.ok():
            rclpy.spin_once(n, timeout_sec=0.1)
    else:
        pub = n.create_publisher(Float64, 'ping', 10)
        got = [0]
        n.create_subscription(Float64, 'pong', lambda m: got.__setitem__(0, got[0] + 1), 10)
        while n.count_subscribers('ping') < 1 or n.count_publishers('pong') < 1:
            rclpy.spin_once(n, timeout_sec=0.05)
        time.sleep(1.0)
        k, end = 0, time.monotonic() + float(sys.argv[2])
        t0 = time.monotonic()
        while time.monotonic() < end:
            pub.publish(Float64(data=float(k)))
            k += 1
            while got[0] < k:
                rclpy.spin_once(n, timeout_sec=1.0)
        print('RESULT', k / (time.monotonic() - t0))
""")


def executable(name):
    from ament_index_python.packages import get_package_prefix
    return str(Path(get_package_prefix('hydropump_ros')) / 'lib' / 'hydropump_ros' / name)


STARTED = []


def start(cmd, log):
    p = subprocess.Popen(cmd, stdout=open(log, 'w'), stderr=subprocess.STDOUT)
    STARTED.append(p)
    return p


def stop(p, sig=signal.SIGTERM):
    if p.poll() is None:
        p.send_signal(sig)
        try:
            p.wait(timeout=20)
        except subprocess.TimeoutExpired:
            p.kill()


def result(proc_out):
    for line in proc_out.splitlines():
        if line.startswith('RESULT'):
            return [float(x) for x in line.split()[1:]]
    raise RuntimeError(proc_out[-2000:])


def python(code, *args, timeout=None):
    return subprocess.run([sys.executable, '-c', code, *map(str, args)], capture_output=True,
                          text=True, timeout=timeout).stdout


def main():
    from domain_coordinator import domain_id
    tmp = Path(tempfile.mkdtemp(prefix='bench_ros_'))
    rows = []
    start_id = random.randrange(100)
    with domain_id(lambda s=[start_id]: (s.__setitem__(0, s[0] + 1) or s[0] % 100 + 1)) as did:
        os.environ['ROS_DOMAIN_ID'] = str(did)
        os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
        sim_cmd = [executable('simulator'), '--ros-args']

        print(f'real-time mode: {DURATION:g} s at factor 1 ...', flush=True)
        sim = start(sim_cmd, tmp / 'sim_rt.log')
        rate, rtf, p99, rtf_diag = result(python(PROBE, DURATION + 4, timeout=DURATION + 60))
        stop(sim)
        print(f'   rate {rate:.1f} Hz, factor {rtf:.3f}, p99 {p99 * 1e3:.3f} ms', flush=True)
        rows += [
            row('real time: joint_states rate seen by a subscriber', rate, 'Hz', '1000'),
            row('real time: achieved real-time factor (/clock vs wall)', rtf, 'x', '1.0'),
            row('real time: p99 |step period - 1 ms|', p99 * 1e3, 'ms', ''),
        ]

        print('free run ...', flush=True)
        sim = start(sim_cmd + ['-p', 'real_time_factor:=0.0'], tmp / 'sim_free.log')
        _, rtf_free, _, _ = result(python(PROBE, 15, timeout=80))
        stop(sim)
        rows.append(row('free run: real-time factor (all topics published)', rtf_free, 'x',
                        '>= 5', rtf_free >= 5))

        print('ping-pong baseline ...', flush=True)
        pong = start([sys.executable, '-c', PINGPONG, 'pong'], tmp / 'pong.log')
        (pp_rate,) = result(python(PINGPONG, 'ping', 10, timeout=80))
        stop(pong)
        rows.append(row('ping-pong baseline: round trips', pp_rate, '1/s'))
        for period in (0.001, 0.005):
            print(f'lock-step, a command every {period * 1e3:g} ms ...', flush=True)
            sim = start(sim_cmd + ['-p', 'lock_step:=true', '-p', 'lock_step_timeout:=2.0',
                                   '-p', f'control_period:={period}'], tmp / 'sim_lock.log')
            resp = start([sys.executable, '-c', RESPONDER, str(period)],
                         tmp / 'responder.log')
            _, rtf_lock, _, _ = result(python(PROBE, 15, 'light', timeout=80))
            stop(resp)
            stop(sim)
            exchanges = rtf_lock / period
            n = int(round(period / 1e-3))
            rows += [
                row(f'lock-step {period * 1e3:g} ms: command exchanges ({n} step(s) each)',
                    exchanges, '1/s'),
                row(f'lock-step {period * 1e3:g} ms: closed-loop steps', rtf_lock / 1e-3, '1/s'),
                # The goal is set at 1 ms, one step an exchange; at 5 ms an exchange carries
                # five steps, and is reported only.
                row(f'lock-step {period * 1e3:g} ms: exchanges / ping-pong',
                    exchanges / pp_rate, 'ratio', '>= 0.5' if n == 1 else '',
                    exchanges / pp_rate >= 0.5 if n == 1 else None),
            ]

        print(f'recorder: {DURATION:g} s of the full topic set at 1 kHz ...', flush=True)
        bag = tmp / 'bag'
        rec = start([executable('recorder'), '--ros-args',
                     '-p', f'output:={bag}', '-p', f'topics:=[{", ".join(SUITE)}]'],
                    tmp / 'rec.log')
        time.sleep(3.0)
        sim = start(sim_cmd + ['-p', 'start_paused:=true'], tmp / 'sim_rec.log')
        python(textwrap.dedent("""
            import time, rclpy
            from rclpy.node import Node
            from std_srvs.srv import Trigger, SetBool
            rclpy.init(); n = Node('bench_ctl')
            def call(srv, name, req):
                c = n.create_client(srv, name); c.wait_for_service(30)
                f = c.call_async(req); rclpy.spin_until_future_complete(n, f, timeout_sec=30)
                return f.result()
            while not call(Trigger, 'recorder/ready', Trigger.Request()).success:
                time.sleep(0.2)
            call(SetBool, 'simulator/pause', SetBool.Request(data=False))
        """), timeout=120)
        time.sleep(DURATION)
        (t_sim,) = result(python(textwrap.dedent("""
            import time, rclpy
            from rclpy.node import Node
            from std_srvs.srv import Trigger, SetBool
            from diagnostic_msgs.msg import DiagnosticArray
            rclpy.init(); n = Node('bench_ctl2')
            diag = []
            n.create_subscription(DiagnosticArray, '/diagnostics', diag.append, 10)
            def call(srv, name, req):
                c = n.create_client(srv, name); c.wait_for_service(30)
                f = c.call_async(req); rclpy.spin_until_future_complete(n, f, timeout_sec=60)
            call(SetBool, 'simulator/pause', SetBool.Request(data=True))
            t = time.monotonic()
            while time.monotonic() < t + 2.5:  # a diagnostics message after the pause
                rclpy.spin_once(n, timeout_sec=0.1)
            call(Trigger, 'recorder/stop', Trigger.Request())
            # The simulator's integrator status (the recorder and controller publish too).
            vals = [{kv.key: kv.value for kv in s.values} for m in diag for s in m.status
                    if s.name == 'simulator: integrator'][-1]
            print('RESULT', vals['sim_time_s'])
        """), timeout=120))
        stop(rec)
        stop(sim)
        from rosbags.rosbag2 import Reader
        with Reader(bag) as r:
            counts = {c.topic.lstrip('/'): c.msgcount for c in r.connections}
            t_end = (r.end_time - r.start_time) * 1e-9
        steps = int(round(t_sim / 1e-3)) + 1  # 1 kHz from t = 0 (the recorder was ready)
        expected = {t: steps for t in SUITE}
        # The applied current of the instant the pause caught is published when it resumes.
        expected['solenoid_current'] = steps - 1
        lost = sum(max(expected[t] - counts.get(t, 0), 0) for t in SUITE)
        published = sum(expected.values())
        print(f'   bag: {counts} over {t_end:.1f} s')
        rows += [
            row('recorder: messages recorded (8 measurement topics)', sum(
                counts.get(t, 0) for t in SUITE), 'msgs'),
            row('recorder: messages lost against steps published', lost, 'msgs', '0',
                lost == 0),
            row('recorder: recorded / published', 1 - lost / published, 'ratio', '1.0'),
        ]
    emit(rows)
    print(f'logs in {tmp}')


if __name__ == '__main__':
    try:
        main()
    finally:
        for proc in STARTED:  # every process this run started, by PID
            stop(proc)
