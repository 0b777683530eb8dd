"""The rule of time without DDS: unstamped messages against /clock (reordered, late, stale),
jumps back, and the controller's supervisor built on it."""

import math

import pytest

from hydropump_ctrl.control import load_config
from hydropump_ctrl.control.supervisor import ControllerNodeConfig, Supervisor, Watchdog
from hydropump_ctrl.timebase import TimeBase
from hydropump_sim.schema import build, ParamError

MS = 1_000_000


def test_unstamped_messages_take_the_latest_clock_sent_before_them():
    tb = TimeBase()
    assert not tb.present and tb.time_of(10) is None
    # /clock of 0, 1, 2 ms published at source times 100, 200, 300.
    for k in range(3):
        assert tb.on_clock(k * MS, 100 * (k + 1)) is None
    assert tb.time_of(150) == 0
    assert tb.time_of(200) == 1 * MS          # published right after the clock of 1 ms
    assert tb.time_of(299) == 1 * MS
    assert tb.time_of(350) == 2 * MS
    assert tb.time_of(50) is None             # before the first clock
    # A message that arrived before the clock that precedes it is not settled yet.
    assert tb.settled(250) and not tb.settled(350)
    tb.on_clock(3 * MS, 400)
    assert tb.settled(350) and tb.time_of(350) == 2 * MS


def test_a_late_message_is_timed_from_the_history():
    tb = TimeBase(history=10)
    for k in range(15):
        tb.on_clock(k * MS, 1000 + 10 * k)
    # Arriving long after its clock, it still gets the clock it was sent after.
    assert tb.time_of(1000 + 10 * 12 + 5) == 12 * MS
    assert tb.after(12 * MS, 1000 + 10 * 12) and not tb.after(12 * MS, 1000 + 10 * 12 - 1)
    assert not tb.after(99 * MS, 10 ** 9)     # an instant never published


def test_time_going_back_is_a_new_simulator():
    tb = TimeBase()
    tb.on_clock(5 * MS, 100)
    tb.on_clock(6 * MS, 200)
    tb.on_clock(6 * MS, 210)                  # the same time twice (a pause) is no jump
    jump = tb.on_clock(0, 300)
    assert jump is not None and jump.old == 6 * MS and jump.new == 0
    assert 'went back from 0.006000 s to 0.000000 s' in jump.describe()
    assert tb.epoch == 1 and tb.latest == 0
    assert tb.time_of(250) is None            # the old history is gone


def test_a_new_writer_is_a_new_simulator_even_if_its_time_is_ahead():
    """A new simulator discovered late may already be past the old one's time: its /clock
    writer's publication sequence numbers start again, and that is a jump too."""
    tb = TimeBase()
    for k in range(1, 4):
        assert tb.on_clock(k * MS, 100 * k, sequence=500 + k) is None
    jump = tb.on_clock(9 * MS, 1000, sequence=1)
    assert jump is not None and (jump.old, jump.new) == (3 * MS, 9 * MS)
    assert 'a new simulator' in jump.describe() and 'went back' not in jump.describe()
    assert tb.epoch == 1 and tb.time_of(350) is None and tb.latest == 9 * MS
    # The new writer's next samples are no jump.
    assert tb.on_clock(10 * MS, 1100, sequence=2) is None


def test_another_writer_identity_is_a_new_simulator():
    """A new simulator discovered after its time and its sequence numbers have both passed
    the old one's: the writer identity (the endpoint GIDs the graph shows) tells them apart."""
    tb = TimeBase()
    for k in range(1, 4):
        assert tb.on_clock(k * MS, 100 * k, sequence=k, writer=('a',)) is None
    assert tb.on_clock(4 * MS, 400, sequence=4, writer=None) is None   # identity unknown
    jump = tb.on_clock(9 * MS, 1000, sequence=9000, writer=('b',))
    assert jump is not None and (jump.old, jump.new) == (4 * MS, 9 * MS)
    assert tb.on_clock(10 * MS, 1100, sequence=9001, writer=('b',)) is None


def test_a_clock_with_an_older_source_time_is_not_mapped():
    tb = TimeBase()
    tb.on_clock(1 * MS, 500)
    assert tb.on_clock(2 * MS, 400) is None   # another publisher's sample, out of order
    assert tb.latest == 1 * MS


# ---- the supervisor ------------------------------------------------------------------------

class Clock:
    def __init__(self):
        self.t = 0.0

    def __call__(self):
        return self.t


@pytest.fixture
def ctrl_config(params):
    from hydropump_sim.params import default_params_path
    return load_config(default_params_path().with_name('controller.yaml'),
                       current_limits=params.I_limits)


def _feed(sup, k, q, p_l=2.0e7, p_u=1.5e7, src0=10 ** 12):
    """The simulator's step k (1 ms): /clock, then the measurements, source times rising."""
    t = k * MS
    src = src0 + 1000 * k
    outs = [sup.clock(t, src)]
    outs.append(sup.measurement('line_pressure', p_l, stamp_ns=t))
    outs.append(sup.measurement('load_pressure', p_u, stamp_ns=t))
    outs.append(sup.measurement('line_flow', q, source_ns=src + 10))
    return [o for o in outs if o is not None]


def test_updates_run_at_control_instants_once_their_measurements_are_in(ctrl_config,
                                                                        params):
    clock = Clock()
    sup = Supervisor(ctrl_config, clock=clock, log=lambda *a: None)
    sup.activate()
    q = 0.5 * params.Q_max
    outs = []
    for k in range(21):
        outs += _feed(sup, k, q)
    # 200 Hz: instants 0, 5, 10, 15, 20 ms; each answered once, stamped with its instant.
    assert [o.stamp_ns for o in outs] == [0, 5 * MS, 10 * MS, 15 * MS, 20 * MS]
    assert sup.counts['stale_updates'] == 0
    # Bumpless: a start at rest commands the current of the measured flow.
    assert outs[0].command == pytest.approx(sup.ctrl._pump.current(q), abs=1e-3)


def test_an_update_waits_for_the_unstamped_flow_of_its_instant(ctrl_config, params):
    clock = Clock()
    sup = Supervisor(ctrl_config, clock=clock, log=lambda *a: None)
    sup.activate()
    q = 0.5 * params.Q_max
    src = 10 ** 12
    assert sup.clock(0, src) is None
    assert sup.measurement('line_pressure', 2e7, stamp_ns=0) is None
    assert sup.measurement('load_pressure', 1.5e7, stamp_ns=0) is None
    # A flow sample sent before the clock of t = 0 (the previous step's) is not fresh.
    assert sup.measurement('line_flow', q, source_ns=src - 5) is None
    out = sup.measurement('line_flow', q, source_ns=src + 5)
    assert out is not None and out.stamp_ns == 0


def test_a_stale_instant_is_updated_after_the_wait(ctrl_config, params):
    clock = Clock()
    sup = Supervisor(ctrl_config, clock=clock, log=lambda *a: None)
    sup.activate()
    for k in range(6):
        _feed(sup, k, 0.5 * params.Q_max)   # a start on the whole operating point
    sup.clock(10 * MS, 10 ** 12 + 10_000)
    assert sup.measurement('line_pressure', 2e7, stamp_ns=10 * MS) is None
    clock.t += 0.05  # the flow of t = 10 ms never comes
    out = sup.measurement('load_pressure', 1.5e7, stamp_ns=10 * MS)
    assert out is not None and out.stamp_ns == 10 * MS
    assert sup.counts['stale_updates'] == 1


def test_a_restarted_simulator_resumes_bumpless_within_one_period(ctrl_config, params):
    logs = []
    clock = Clock()
    sup = Supervisor(ctrl_config, clock=clock, log=lambda lvl, txt: logs.append(txt))
    sup.activate()
    q = 0.4 * params.Q_max
    assert sup.set_reference(q) is None  # a loop at rest on the measured flow
    for k in range(200):
        _feed(sup, k, q)
    before = sup.ctrl.command
    assert before == pytest.approx(sup.ctrl._pump.current(q), abs=2e-3)
    # A new simulator: time starts at 0 again, same plant state.
    outs = []
    for k in range(6):
        outs += _feed(sup, k, q, src0=2 * 10 ** 12)
    assert sup.counts['time_jumps'] == 1 and any('went back' in t for t in logs)
    assert [o.stamp_ns for o in outs] == [0, 5 * MS]
    assert outs[0].command == pytest.approx(before, abs=2e-3)


def test_a_lock_step_watchdog_counts_simulation_time_not_wall_seconds(ctrl_config, params):
    """With watchdog.simulation_time a simulation held back for minutes (a slow recorder, a
    loaded machine) trips nothing; measurements lost while its clock runs do, after the
    same timeouts in simulation time."""
    clock = Clock()
    sup = Supervisor(ctrl_config, Watchdog(hold_timeout=0.2, safe_timeout=1.0,
                                           simulation_time=True), clock=clock,
                     log=lambda *a: None)
    sup.activate()
    for k in range(10):
        _feed(sup, k, 0.5 * params.Q_max)
    clock.t += 120.0                     # the clock stands still for two minutes of wall time
    assert sup.check_watchdog() is None and sup.mode_state == 'running'
    # The clock runs on without measurements: 0.3 s of simulation time holds, 1.5 s is safe.
    sup.clock(309 * MS, 10 ** 12 + 400_000)
    assert sup.check_watchdog() is None and sup.mode_state == 'hold'
    sup.clock(1509 * MS, 10 ** 12 + 500_000)
    out = sup.check_watchdog()
    assert sup.mode_state == 'safe' and out.command == ctrl_config.limits.safe_current
    # The steady-clock default trips on the same stall.
    wall = Supervisor(ctrl_config, Watchdog(hold_timeout=0.2, safe_timeout=1.0), clock=clock,
                      log=lambda *a: None)
    wall.activate()
    for k in range(10):
        _feed(wall, k, 0.5 * params.Q_max)
    clock.t += 2.0
    assert wall.check_watchdog() is not None and wall.mode_state == 'safe'


def test_watchdog_holds_then_commands_the_safe_current_then_resumes(ctrl_config, params):
    clock = Clock()
    sup = Supervisor(ctrl_config, Watchdog(hold_timeout=0.2, safe_timeout=1.0), clock=clock,
                     log=lambda *a: None)
    sup.activate()
    for k in range(10):
        _feed(sup, k, 0.5 * params.Q_max)
    clock.t += 0.3
    assert sup.check_watchdog() is None and sup.mode_state == 'hold'
    sup.clock(10 * MS, 10 ** 12 + 10_000)
    assert sup.mode_state == 'hold'  # a /clock alone is no measurement: still holding
    clock.t += 1.5
    out = sup.check_watchdog()
    assert sup.mode_state == 'safe' and out.command == ctrl_config.limits.safe_current
    assert out.stamp_ns == 10 * MS  # stamped with the latest simulation time
    # The first measurement back restarts the law at the next instant (bumplessly).
    outs = []
    for k in range(11, 21):
        outs += _feed(sup, k, 0.5 * params.Q_max)
    assert sup.mode_state == 'running'
    # The instant that came due while holding (10 ms) is served as soon as it can be.
    assert [o.stamp_ns for o in outs] == [10 * MS, 15 * MS, 20 * MS]
    assert outs[0].command == pytest.approx(sup.ctrl._pump.current(0.5 * params.Q_max),
                                            abs=2e-3)


def test_a_first_instant_whose_clock_went_by_is_served_from_the_stamps(ctrl_config, params):
    """A lock-step simulator's first /clock sent before this node matched it: the stamps of
    t = 0 make the instant due, so the simulator gets its command."""
    clock = Clock()
    sup = Supervisor(ctrl_config, clock=clock, log=lambda *a: None)
    sup.activate()
    q = 0.5 * params.Q_max
    assert sup.measurement('line_pressure', 2e7, stamp_ns=0) is None
    assert sup.measurement('load_pressure', 1.5e7, stamp_ns=0) is None
    assert sup.measurement('line_flow', q, source_ns=50) is None   # its time is unknown
    clock.t += 0.05
    out = sup.measurement('line_pressure', 2e7, stamp_ns=0)
    assert out is not None and out.stamp_ns == 0


def test_a_restart_waits_for_the_whole_operating_point(ctrl_config, params):
    """Late measurements (a loaded machine) never make a bumpless start from a guess."""
    clock = Clock()
    sup = Supervisor(ctrl_config, clock=clock, log=lambda *a: None)
    sup.activate()
    sup.clock(0, 100)
    clock.t += 0.5  # long past the stale wait, with nothing measured yet
    assert sup.measurement('line_pressure', 2e7, stamp_ns=0) is None
    assert sup.measurement('load_pressure', 1.5e7, stamp_ns=0) is None
    q = 0.4 * params.Q_max
    assert sup.set_reference(q) is None
    out = sup.measurement('line_flow', q, source_ns=200)
    assert out.command == pytest.approx(sup.ctrl._pump.current(q), abs=2e-3)


def test_measurement_gate_rejects_faults(ctrl_config):
    sup = Supervisor(ctrl_config, clock=Clock(), log=lambda *a: None)
    sup.measurement('line_flow', math.nan, source_ns=1)
    sup.measurement('line_pressure', -5.0, stamp_ns=0)
    sup.measurement('line_flow', 5.0, source_ns=2)
    assert sup.counts['rejected_nan'] == 1 and sup.counts['rejected_range'] == 2


def test_live_parameters_are_checked(ctrl_config):
    sup = Supervisor(ctrl_config, clock=Clock(), log=lambda *a: None)
    assert sup.set_parameters({'emc.tau_control': 0.0}).startswith('emc.tau_control = 0 s')
    assert 'read-only' in sup.set_parameters({'model.tau': 0.2})
    assert 'must not be shorter' in sup.set_parameters({'watchdog.safe_timeout': 0.1})
    assert sup.set_parameters({'watchdog.hold_timeout': 0.3}) is None
    assert sup.watchdog.hold_timeout == 0.3
    assert sup.set_parameters({'emc.tau_control': 0.02}) is None
    assert sup.config.emc.tau_control == 0.02
    with pytest.raises(ParamError, match='must not be shorter'):
        build(ControllerNodeConfig, {'watchdog': {'hold_timeout': 1.0, 'safe_timeout': 0.5}})


def test_wall_time_only_when_no_clock_exists_for_clock_wait(ctrl_config):
    """A controller on a real pump (no /clock anywhere) updates on its steady timer, stamped
    with wall time, but only after CLOCK_WAIT of measurements with no /clock publisher: a
    simulator's /clock discovered late must never meet a wall-time command."""
    clock = Clock()
    sup = Supervisor(ctrl_config, clock=clock, log=lambda *a: None)
    sup.activate()

    def measurements():
        sup.measurement('line_flow', 5.0e-4, source_ns=int(clock.t * 1e9))
        sup.measurement('line_pressure', 1.6e7, stamp_ns=None)
        sup.measurement('load_pressure', 1.2e7, stamp_ns=None)

    measurements()
    for t in (0.5, Supervisor.CLOCK_WAIT - 0.1):
        clock.t = t
        measurements()
        assert sup.wall_tick(10 ** 18) is None
    clock.t = Supervisor.CLOCK_WAIT + 0.1
    measurements()
    assert sup.wall_tick(10 ** 18, clock_publishers=1) is None   # a simulator is there
    out = sup.wall_tick(10 ** 18)
    assert out is not None and out.stamp_ns == 10 ** 18


def test_a_live_algorithm_switch_is_bumpless(ctrl_config, params):
    """EMC at rest on a flow reference, then ``controller.algorithm: pi`` set live: the next
    update runs the PI law, starting from the present command, and the loop stays at rest."""
    sup = Supervisor(ctrl_config, clock=Clock(), log=lambda *a: None)
    sup.activate()
    q = 0.4 * params.Q_max
    assert sup.set_reference(q) is None
    for k in range(200):
        _feed(sup, k, q)
    before = sup.ctrl.command
    assert sup.ctrl.algorithm == 'emc'
    assert sup.set_parameters({'controller.algorithm': 'pi'}) is None
    outs = []
    for k in range(200, 400):
        outs += _feed(sup, k, q)
    assert sup.ctrl.algorithm == 'pi'
    # The flow sits on its reference: the PI integrator keeps the transferred command.
    assert max(abs(o.command - before) for o in outs) < 1e-3
    with pytest.raises(ParamError, match='make_controller builds the other one'):
        sup.ctrl.set_config({'controller.algorithm': 'emc'})


def test_a_restart_after_a_reset_ignores_the_current_from_before_it(ctrl_config, params):
    """A persistent graph between two experiments: the controller is restarted (lifecycle),
    the simulator reset to a new equilibrium whose samples come at the next instant, without
    the current (published once the command is in). The law restarts from the new flow, not
    from the current of the previous experiment."""
    sup = Supervisor(ctrl_config, clock=Clock(), log=lambda *a: None)
    sup.activate()
    q_old, q_new = 0.7 * params.Q_max, 0.3 * params.Q_max
    assert sup.set_reference(q_old) is None
    for k in range(50):
        _feed(sup, k, q_old)
        sup.measurement('solenoid_current', sup.ctrl._pump.current(q_old),
                        source_ns=10 ** 12 + 1000 * k + 20)
    sup.deactivate()
    assert sup.set_parameters({'reference.flow': q_new}) is None
    sup.activate()
    outs = _feed(sup, 55, q_new)   # the reset state, at the next instant
    assert len(outs) == 1
    assert outs[0].command == pytest.approx(sup.ctrl._pump.current(q_new), abs=2e-3)


def test_a_controller_that_never_had_a_measurement_warns_after_its_timeout(ctrl_config,
                                                                          params):
    clock = Clock()
    logs = []
    sup = Supervisor(ctrl_config, Watchdog(hold_timeout=0.2, safe_timeout=1.0), clock=clock,
                     log=lambda lvl, txt: logs.append((lvl, txt)))
    sup.activate()
    clock.t = 0.9
    sup.check_watchdog()
    assert sup.status() == ('ok', 'ok') and not logs   # discovery may take that long
    clock.t = 1.1
    sup.check_watchdog()
    sup.check_watchdog()
    assert sup.status() == ('warn', 'no measurement received yet')
    assert sup.diagnostics()['measurements_received'] is False
    assert [lvl for lvl, txt in logs if 'no measurement' in txt] == ['warn']  # said once
    # A measurement ends it; later silence is the watchdog's (stale, then lost).
    _feed(sup, 0, 1.0e-3)
    assert sup.status() == ('ok', 'ok')
    clock.t = 1.5
    sup.check_watchdog()
    assert sup.status() == ('warn', 'measurements stale: holding')
