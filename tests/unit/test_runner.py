"""The simulator node's logic without DDS: the Runner's gate, watchdog, pause-at, reset,
command checks, pacing order and its configuration checks."""

import math
import threading

import numpy as np
import pytest

from hydropump_sim import equilibrium, IntegratorConfig, simulate, Simulator
from hydropump_sim.runner import Runner, SimulatorConfig
from hydropump_sim.schema import build, ParamError
from hydropump_sim.sensors import profile_from_dict


class FakeClock:
    """A steady clock that advances by ``tick`` at every reading."""

    def __init__(self, tick=0.0):
        self.t = 0.0
        self.tick = tick

    def __call__(self):
        self.t += self.tick
        return self.t

    def sleep(self, s):
        self.t += s


class Sink:
    """Collects what the runner publishes; stops it after ``n`` measurements; ``on_frame``
    runs on each one (e.g. a stand-in controller)."""

    def __init__(self, runner, n, on_frame=None):
        self.runner = runner
        self.n = n
        self.on_frame = on_frame
        self.events = []
        self.frames = []

    def current(self, t, value):
        self.events.append(('current', t, value))

    def measurement(self, frame):
        self.events.append(('measurement', frame.t))
        self.frames.append(frame)
        if self.on_frame:
            self.on_frame(self, frame)
        if len(self.frames) >= self.n:
            self.runner.stop()


def cfg(**kw):
    return build(SimulatorConfig, kw)


def still():
    """A steady clock that stands still unless slept on: the watchdog never trips however
    long a step takes (a first one compiles; a loaded machine)."""
    clock = FakeClock()
    return {'clock': clock, 'sleep': clock.sleep}


def run(runner, sink, timeout=60.0):
    th = threading.Thread(target=runner.run, args=(sink,), daemon=True)
    th.start()
    th.join(timeout)
    assert not th.is_alive(), 'the runner did not stop'


def test_publish_rate_must_divide_the_step_rate():
    with pytest.raises(ParamError, match=r'publish_rate = 400 Hz.*nearest rates are 333\.333 '
                                         r'and 500 Hz'):
        cfg(publish_rate=400.0)
    with pytest.raises(ParamError, match=r'publish_rate = 10000 Hz: faster than 1/dt = 1000 '
                                         r'Hz.*1000, 500, 333\.333'):
        cfg(publish_rate=10000.0)
    with pytest.raises(ParamError, match='control_period = 0.0055 s: not a whole number'):
        cfg(control_period=0.0055)
    assert cfg(publish_rate=250.0).publish_every == 4
    assert cfg(dt=1e-4, publish_rate=10000.0).publish_every == 1


def test_currents_are_checked_against_eq_2(params):
    lo, hi = params.I_limits
    assert cfg(safe_current=hi + 0.1).plant_checks(params)[0].startswith('safe_current = ')
    assert not cfg().plant_checks(params)
    r = Runner(Simulator(params), cfg())
    assert r.safe_current == pytest.approx(params.current_range[0])
    assert r.initial_current == pytest.approx(params.I_nominal)


def test_free_run_matches_simulate_and_publishes_current_before_the_step(params):
    r = Runner(Simulator(params), cfg(real_time_factor=0.0, initial_current=0.46), **still())
    r.command(0.54)
    sink = Sink(r, 201)
    run(r, sink)
    t = np.array([f.t for f in sink.frames])
    np.testing.assert_allclose(t, np.arange(201) * 1e-3, atol=1e-12)
    # Per step: the applied current of t_k, then the measurements of t_k+1.
    assert sink.events[0] == ('measurement', 0.0)
    assert sink.events[1][0] == 'current' and sink.events[1][1] == 0.0
    assert sink.events[2] == ('measurement', pytest.approx(1e-3))
    # The same plant offline, stepped as the node steps (a step ending at every increment):
    # from the equilibrium at 0.46 A, 0.54 A held from t = 0.
    ref = simulate(params, 0.2, 0.54, x0=equilibrium(params, 0.46).x, dt_out=1e-3,
                   config=IntegratorConfig())
    q = np.array([f.signals['line_flow'] for f in sink.frames])
    np.testing.assert_allclose(q, ref.q_l, rtol=1e-6, atol=1e-12)


def test_nan_commands_are_refused_and_out_of_range_clamped(params):
    logs = []
    r = Runner(Simulator(params), cfg(real_time_factor=0.0), **still(),
               log=lambda lvl, txt: logs.append((lvl, txt)))
    r.command(math.nan)
    assert r.stats['nan_commands'] == 1
    r.command(5.0)
    assert r.stats['clamped_commands'] == 1
    sink = Sink(r, 2)
    run(r, sink)
    lo, hi = params.I_limits
    assert r.sim.u[0] == pytest.approx(hi)  # the absolute current held
    assert any('non-finite' in t for _, t in logs) and any('clamped' in t for _, t in logs)
    # Diagnostics report the current the plant holds, the command beside it.
    d = r.diagnostics()
    assert d['applied_current'] == pytest.approx(hi) and d['commanded_current'] == 5.0
    r.command(-1.0e9)
    r._inputs()
    assert r.diagnostics()['applied_current'] == pytest.approx(lo)
    # A NaN after that says what the plant holds (the clamped current), not the 1e9 asked.
    r._warned.clear()
    r.command(math.nan)
    assert logs[-1][1].endswith(f'holding {lo:.4g} A')


def test_a_pause_at_already_passed_says_it_pauses_now(params):
    logs = []
    r = Runner(Simulator(params), cfg(real_time_factor=0.0), **still(),
               log=lambda lvl, txt: logs.append((lvl, txt)))
    run(r, Sink(r, 20))
    r.set_parameter('pause_at', 0.005)
    assert logs[-1] == ('warn', 'pause_at = 0.005 s has already passed (t = 0.019 s): '
                                'pausing now')
    r.set_parameter('pause_at', 5.0)
    assert logs[-1][1].startswith('pause_at = 0.005')   # a time ahead says nothing


def test_command_watchdog_applies_the_safe_current_and_releases(params):
    clock = FakeClock(tick=0.0)
    r = Runner(Simulator(params), cfg(real_time_factor=0.0, command_timeout=0.5),
               clock=clock, sleep=clock.sleep)
    r.command(0.6)
    applied, reported = [], []

    def on_frame(sink, frame):
        clock.t += 0.01  # 10 ms of wall time per step
        applied.append(r.sim.u[0])
        reported.append(r.diagnostics()['applied_current'])
        if len(sink.frames) == 80:
            r.command(0.6)

    sink = Sink(r, 100, on_frame)
    run(r, sink)
    applied = np.array(applied)
    # 0.5 s after the command (50 steps of 10 ms) the safe current holds, until step 80.
    assert applied[45] == pytest.approx(0.6)
    assert np.allclose(applied[55:79], r.safe_current)
    assert applied[85] == pytest.approx(0.6)
    assert r.stats['watchdog_trips'] == 1
    # Diagnostics say what the plant held at every step, the safe current included.
    np.testing.assert_allclose(reported, applied)
    assert r.safe_current != pytest.approx(0.6)


def test_lock_step_advances_one_period_per_command(params):
    r = Runner(Simulator(params), cfg(lock_step=True, lock_step_timeout=30.0))
    seen = []

    def on_frame(sink, frame):
        k = int(round(frame.t / 0.005 * 1e3)) / 1e3
        if k == int(k):  # a control instant: answer once, as a controller does
            seen.append(frame.t)
            r.command(0.5)

    sink = Sink(r, 51, on_frame)
    run(r, sink)
    assert r.stats['lock_step_timeouts'] == 0
    assert len(seen) == 11 and seen[-1] == pytest.approx(0.05)


def test_lock_step_sends_the_first_instant_again_to_a_controller_matched_late(params):
    """A controller whose subscription matched just after the first instant went out misses
    it (discovery is not symmetric): the first measurements go out again each second until
    a command comes, unchanged, and the run goes on without waiting out its timeout."""
    r = Runner(Simulator(params), cfg(lock_step=True, lock_step_timeout=30.0))
    seen = []

    def on_frame(sink, frame):
        seen.append(frame.t)
        if len(seen) == 1:
            return          # not matched yet: this one went to nobody
        k = int(round(frame.t / 0.005 * 1e3)) / 1e3
        if k == int(k):
            r.command(0.5)

    sink = Sink(r, 12, on_frame)
    run(r, sink)
    assert r.stats['lock_step_timeouts'] == 0
    assert seen[:2] == [0.0, 0.0] and sink.frames[0] is sink.frames[1]
    assert seen[2] == pytest.approx(0.001)


def test_lock_step_without_commands_times_out_and_counts(params):
    r = Runner(Simulator(params), cfg(lock_step=True, lock_step_timeout=0.01))
    sink = Sink(r, 11)
    run(r, sink)
    assert r.stats['lock_step_timeouts'] == 2  # at t = 0 and t = 5 ms


def test_pause_at_pauses_once_and_resumes(params):
    r = Runner(Simulator(params), cfg(real_time_factor=0.0, pause_at=0.01), **still())
    sink = Sink(r, 10_000)
    th = threading.Thread(target=r.run, args=(sink,), daemon=True)
    th.start()
    for _ in range(2000):
        if r.paused:
            break
        threading.Event().wait(0.005)
    assert r.paused and r.sim.steps == 10
    r.set_paused(False)
    sink.n = len(sink.frames) + 20
    th.join(30)
    assert not th.is_alive() and r.sim.steps >= 30


def test_reset_returns_to_equilibrium_and_time_runs_on(params):
    r = Runner(Simulator(params), cfg(real_time_factor=0.0, initial_current=0.46), **still())
    x0 = r.sim.x.copy()

    def on_frame(sink, frame):
        if len(sink.frames) == 5:
            r.command(0.7)
        if len(sink.frames) == 60:
            r.reset()

    sink = Sink(r, 62, on_frame)
    run(r, sink)
    assert sink.frames[-1].t == pytest.approx(0.061)
    # One increment after the reset the state is close to the initial equilibrium again.
    assert sink.frames[-1].signals['actuator_position'] == pytest.approx(x0[2], abs=2e-5)


def test_live_inputs_apply_before_the_next_increment(params):
    r = Runner(Simulator(params), cfg(real_time_factor=0.0), **still())

    def on_frame(sink, frame):
        if len(sink.frames) == 3:
            r.set_parameter('line.xi_u', 0.3)

    sink = Sink(r, 5, on_frame)
    run(r, sink)
    assert r.sim.u[2] == pytest.approx(0.3)


def test_sensor_models_act_on_the_published_signals(params):
    prof = profile_from_dict({'sensors': {'line_flow': {'quantum': 1e-5}, 'seed': 3}})
    r = Runner(Simulator(params), cfg(real_time_factor=0.0), profile=prof, **still())
    sink = Sink(r, 20)
    run(r, sink)
    q = np.array([f.signals['line_flow'] for f in sink.frames])
    assert np.allclose(q / 1e-5, np.round(q / 1e-5))
    p = np.array([f.signals['pump_flow'] for f in sink.frames])
    assert not np.allclose(p / 1e-5, np.round(p / 1e-5))


def test_a_reset_while_paused_starts_the_next_experiment_at_the_next_control_instant(params):
    """What a persistent graph does between two experiments: paused at the end of one, new
    operating point, initial current and noise seed, reset. The reset state (the equilibrium
    of eqs. 1-9 at the new point) is published at once, at the next control instant, and the
    lock-step run waits there for the controller's command."""
    prof = profile_from_dict({'sensors': {'line_pressure': {'noise_std': 1.0e5}, 'seed': 1}})
    r = Runner(Simulator(params), cfg(lock_step=True, lock_step_timeout=30.0, pause_at=0.013),
               profile=prof)
    sink = Sink(r, 10_000)

    def answer(sink, frame):  # a stand-in controller: one command per control instant
        if round(frame.t * 1e6) % 5000 == 0:
            r.command(r.initial_current)  # the plant stays at its equilibrium

    sink.on_frame = answer
    th = threading.Thread(target=r.run, args=(sink,), daemon=True)
    th.start()
    for _ in range(4000):
        if r.paused and r.sim.steps == 13:
            break
        threading.Event().wait(0.005)
    assert r.paused and r.sim.steps == 13
    noise_1 = [f.signals['line_pressure'] for f in sink.frames]
    n_before = len(sink.frames)
    r.set_parameter('line.P_u', 1.5e7)
    r.set_parameter('initial_current', 0.6)
    r.set_parameter('sensors.seed', 2)
    r.reset()
    for _ in range(4000):
        if len(sink.frames) > n_before:
            break
        threading.Event().wait(0.005)
    threading.Event().wait(0.05)
    # Published at once, while paused, at 15 ms (the next instant after 13 ms), once.
    assert len(sink.frames) == n_before + 1 and r.paused
    f = sink.frames[-1]
    assert f.t == pytest.approx(0.015)
    eq = equilibrium(params, 0.6, load_pressure=1.5e7)
    assert f.signals['actuator_position'] == pytest.approx(eq.x[2], rel=1e-9)
    assert f.signals['load_pressure'] == pytest.approx(1.5e7)
    r.set_paused(False)
    sink.n = len(sink.frames) + 20
    th.join(30)
    assert not th.is_alive()
    t = np.array([fr.t for fr in sink.frames])
    assert np.all(np.diff(t) > 0)  # time never repeats across the reset
    assert r.stats['lock_step_timeouts'] == 0
    # The new seed gives another noise stream: the first samples differ from the first run's.
    noise_2 = [fr.signals['line_pressure'] - sink.frames[n_before].signals['line_pressure']
               for fr in sink.frames[n_before:n_before + 10]]
    assert not np.allclose(np.diff(noise_2), np.diff(noise_1[:10]))


def test_lock_step_needs_a_sample_at_every_control_instant():
    # 500 Hz samples every 2 ms: the 5 ms instants would never be published, and a lock-step
    # run would wait for a command that no controller can send.
    with pytest.raises(ParamError, match=r'publish_rate = 500 Hz: lock-step needs a sample at '
                                         r'every control instant.*e\.g\. 1000 or 200 Hz'):
        cfg(lock_step=True, publish_rate=500.0)
    assert cfg(lock_step=True, publish_rate=200.0).publish_every == 5
    assert cfg(lock_step=False, publish_rate=500.0).publish_every == 2


def test_step_costs_are_reported_against_the_period_and_overruns_warn(params):
    """Every step's wall time is kept: /diagnostics gives its p50, p99 and max against the
    period; a paced step longer than its period counts and warns (throttled)."""
    logs = []
    clock = FakeClock()
    r = Runner(Simulator(params), cfg(real_time_factor=1.0), clock=clock, sleep=clock.sleep,
               log=lambda level, text: logs.append((level, text)))
    run(r, Sink(r, 50))
    d = r.diagnostics()
    assert 0.0 < d['step_cost_p50'] <= d['step_cost_p99'] <= d['step_cost_max']
    assert d['step_budget'] == pytest.approx(1e-3)
    # No real step takes a microsecond: at 1000x real time every one is over its period.
    fast = Runner(Simulator(params), cfg(real_time_factor=1000.0), clock=clock,
                  sleep=clock.sleep, log=lambda level, text: logs.append((level, text)))
    run(fast, Sink(fast, 20))
    d = fast.diagnostics()
    assert d['step_budget'] == pytest.approx(1e-6)
    assert d['overruns'] >= 19
    assert [t for lvl, t in logs if lvl == 'warn' and 'over its 0.001 ms period' in t]


def test_an_integration_failure_says_why_in_words_on_the_simulation_clock(params):
    """A stepper failure is reported at the simulation time the user sees, with its reason
    in words (it was a status code)."""
    from hydropump_sim.simulate import IntegrationError
    sim = Simulator(params)
    for _ in range(3):
        sim.step()
    sim.u[0] = math.nan           # what no range check lets through: a NaN inside
    with pytest.raises(IntegrationError) as exc:
        sim.step()
    assert str(exc.value) == ('integration failed at t = 0.003 s of simulation time: '
                              'non-finite state (a parameter or input far outside its range?)')


def test_a_reset_puts_a_cylinder_back_where_the_circuit_file_starts_it():
    """A cylinder has no rest position (its position integrates its flow): a reset after
    the boom moved puts it back at the ``x0`` its circuit file gives (read here as plain
    YAML), with the valve closed again and the boom at rest."""
    import yaml

    from hydropump_sim.circuit import load_circuit

    from ..conftest import ROOT
    path = ROOT / 'config' / 'circuits' / 'fig1.yaml'
    x0 = yaml.safe_load(path.read_text())['components']['boom']['cylinder']['x0']
    sim = Simulator(load_circuit(str(path)), dt=1e-3)
    pos = sim.model.states.index('boom.cylinder.position')
    vel = sim.model.states.index('boom.cylinder.velocity')
    assert sim.x[pos] == pytest.approx(x0, abs=1e-9)
    sim.set_input('pump.current', 0.9 * sim.model.input_ranges[0][1])
    sim.set_input('boom.valve.command', 1.0)
    peak = 0.0
    for _ in range(300):
        sim.step()
        peak = max(peak, abs(sim.x[vel]))
    assert abs(sim.x[pos] - x0) > 1e-3  # the boom moved
    sim.set_input('boom.valve.command', 0.0)
    sim.reset(keep_time=True)
    assert sim.x[pos] == pytest.approx(x0, abs=1e-9)
    # At rest: at most the held boom's drift past its closed valve's leakage.
    assert abs(sim.x[vel]) < 0.01 * peak
