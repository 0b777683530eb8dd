"""A circuit in closed loop, without ROS: the circuit stepped at 1 kHz, the bench's sensors,
and the pump under one of three controls, as the simulator and controller nodes run it:

- ``margin`` (the default): the electronic load-sensing control, EMC or PI in margin mode,
  regulating ``P_l - P_LS`` against the highest load;
- ``open``: the pump's current as scheduled (or held);
- ``hydromechanical``: the classic load-sensing compensator on the pump instead of the
  solenoid (the ``ls_pump`` component), for comparison.

The controller's embedded model is the pump's (``config/controller.yaml`` beside the
circuit's plant file, or designed from the plant) with the line capacitance the circuit
presents at the pump's outlet (:func:`hydropump_sim.circuit_analysis.line_capacitance`):
the simplified circuit model the controller needs.
"""

from __future__ import annotations

from collections.abc import Mapping
import dataclasses
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from hydropump_sim import invariants
from hydropump_sim.circuit import Circuit, CircuitError
from hydropump_sim.circuit_analysis import line_capacitance
from hydropump_sim.circuit_sim import CircuitSimulator, equilibrium, input_table
from hydropump_sim.errors import InputError
from hydropump_sim.inputs import Signal
from hydropump_sim.sensors import SensorBank, SensorConfig, SensorProfile

from ..control import ControllerConfig, load_config, make_controller
from ..control.design import pi_margin_compensated_tuning

CONTROLS = ('margin', 'open', 'hydromechanical')
#: The hydromechanical compensator's default margin [Pa] without a controller configuration.
MARGIN = 2.0e6


@dataclass
class CircuitRun:
    """One run: every signal of the circuit on the simulator's grid (``run['boom.flow']``),
    the inputs, and what the controller saw and did."""

    circuit: Circuit
    t: np.ndarray
    y: np.ndarray
    u: np.ndarray
    control: str
    algorithm: str | None = None
    margin: float | None = None
    t_ctrl: np.ndarray = field(default_factory=lambda: np.zeros(0))
    meas: dict = field(default_factory=dict)
    info: dict = field(default_factory=dict)

    def __getitem__(self, name: str) -> np.ndarray:
        return self.y[:, self.circuit.signal_index(name)]

    def input(self, name: str) -> np.ndarray:
        return self.u[:, self.circuit.input_index(name)]

    def final(self) -> dict[str, float]:
        return {n: float(self[n][-1]) for n in self.circuit.component_signals()}


def hydromechanical(circuit: Circuit, margin: float) -> Circuit:
    """The same circuit with its pump under the hydromechanical compensator at ``margin``."""
    pump = circuit.pump()
    if pump is None:
        raise CircuitError([f'{circuit.name}: no pump to put under load-sensing control'])
    if 'ls' not in pump.comp.ports:
        raise CircuitError([f'{pump.comp.name}: its port ls is not connected: the '
                            'hydromechanical compensator needs the load-sensing line'])
    return circuit.with_values({f'{pump.comp.name}.type': 'ls_pump',
                                f'{pump.comp.name}.ls.margin': margin})


def controller_config(circuit: Circuit, eq=None, config: ControllerConfig | None = None
                      ) -> ControllerConfig:
    """The controller for a circuit: ``config`` (default ``controller.yaml`` beside the
    circuit's plant file, else designed from the plant) with the line capacitance the
    circuit presents at the pump's outlet."""
    pump = circuit.pump()
    plant = pump.comp.params.plant
    if config is None:
        src = Path(circuit.source).parent
        found = None
        for cand in (src / 'controller.yaml', src.parent / 'controller.yaml'):
            if cand.is_file():
                found = cand
                break
        if found is not None:
            config = load_config(found, current_limits=plant.I_limits)
        else:
            from ..control.design import design_config
            config = design_config(plant)
    eq = equilibrium(circuit) if eq is None else eq
    node = pump.comp.ports['out'][0]
    values = {'model.C_l': line_capacitance(circuit, eq, node)}
    if 'ls_pressure' in circuit.measured():
        # Compensated sections: the line an integrator for EMC's model and PI's tuning,
        # with the relief valve at the pump's outlet (the lowest cracking) in EMC's model.
        values['model.load_law'] = 'compensated'
        values['controller.mode'] = 'margin'  # what a load-sensing circuit's pump runs
        # The compensators' setting (the highest): below it the loads starve. Post
        # compensators leave the metering edges the margin less their spring.
        settings = [pt.comp.metering_drop(config.reference.margin)
                    for pt in circuit.role('compensator')]
        if settings:
            values['model.dp_compensator'] = max(settings)
        reliefs = [pt.comp.relief_law() for pt in circuit.role('pressure_limit')
                   if pt.comp.relief_law() and pt.comp.ports['in'][0] == node]
        if reliefs:
            crack, full, q_full = min(reliefs)
            values.update({'model.relief_crack': crack, 'model.relief_full': full,
                           'model.relief_q_full': q_full})
        model = {**dataclasses.asdict(config.model), 'C_l': values['model.C_l']}
        values['pi.margin.p'], values['pi.margin.i'] = pi_margin_compensated_tuning(
            model, config.period)
    return config.replace(values)


def _margin_of(circuit: Circuit):
    m = circuit.measured()
    ref = m.get('ls_pressure') or m.get('load_pressure')
    if ref is None:
        raise CircuitError([f'{circuit.name}: no load-sensing pressure (a shuttle network) '
                            'nor load pressure: margin control needs one'])
    i_l, i_r = circuit.signal_index(m['line_pressure']), circuit.signal_index(ref)
    return lambda y: y[i_l] - y[i_r]


def start_current(circuit: Circuit, eq, share: float = 1.0) -> float:
    """A current to close the margin loop from: the one whose pump flow (eq. 11) is
    ``share`` of the flow the loads take at the steady state ``eq`` (what its relief valves
    pass is surplus). The open-loop steady state of a given margin is ill-conditioned
    (flow-controlled loads take the same flow at any margin), so the loop starts here and
    settles the margin; below 1 the start is the well-posed rest of loads that starve a
    little."""
    pump = circuit.pump()
    plant = pump.comp.params.plant
    n = pump.comp.name
    surplus = sum(eq[f'{pt.comp.name}.flow'] for pt in circuit.role('pressure_limit'))
    q = share * max(eq[f'{n}.q_l'] - surplus, 0.0)
    speed = eq.u[circuit.input_index(f'{n}.shaft_speed')]
    disp = q / (plant.pump.V_p * speed)
    i_s = (disp - 0.5) * plant.stroke_scale * plant.spool.K_a / plant.spool.phi_s
    lo, hi = plant.current_range
    return min(max(plant.I_nominal + i_s, lo), hi)


def run_circuit(circuit: Circuit, duration: float,
                inputs: Mapping[str, Signal] | None = None, *, control: str = 'margin',
                algorithm: str | None = None, margin: float | None = None,
                config: ControllerConfig | None = None, profile: SensorProfile | None = None,
                settle: float | None = None, dt: float = 1.0e-3) -> CircuitRun:
    """Run a circuit for ``duration`` [s] with scheduled ``inputs`` under ``control``.

    Parameters
    ----------
    inputs : mapping
        Input name -> number or function of time (``boom.command``, ``motor.torque``).
    control : {'margin', 'open', 'hydromechanical'}
    algorithm : {'emc', 'pi'}, optional
        Margin control's law (default the configuration's).
    margin : float, optional
        Margin [Pa] (default the configuration's ``reference.margin``).
    config : ControllerConfig, optional
        Margin control's configuration, as given (default: :func:`controller_config`, the
        design for this circuit).
    profile : SensorProfile, optional
        The sensors the controller sees the circuit through (default ideal).
    settle : float, optional
        Time [s] run before ``t = 0`` with the inputs of ``t = 0``, not recorded: the loop
        settles from its start (default 1.5 s under margin control, 0 otherwise).
    """
    if control not in CONTROLS:
        raise InputError(f'control {control!r}: choose one of {", ".join(CONTROLS)}')
    if control == 'margin':
        cfg = config if config is not None else controller_config(circuit)
        changes = {'controller.mode': 'margin'}
        if algorithm is not None:
            changes['controller.algorithm'] = algorithm
        if margin is not None:
            changes['reference.margin'] = margin
        cfg = cfg.replace(changes)
        margin = cfg.reference.margin
    elif control == 'hydromechanical':
        margin = margin if margin is not None else (config.reference.margin if config
                                                    else MARGIN)
        circuit = hydromechanical(circuit, margin)
    settle = (1.5 if control == 'margin' else 0.0) if settle is None else settle
    n, n0 = int(round(duration / dt)), int(round(settle / dt))
    t = np.arange(n + 1) * dt
    U = input_table(circuit, np.maximum(np.arange(-n0, n + 1) * dt, 0.0), inputs, dt)
    pump = circuit.pump()
    cur = f'{pump.comp.name}.current' if circuit.electric_pump() else None
    sim = CircuitSimulator(circuit, dt)
    eq = equilibrium(circuit, U[0])
    sim.x, sim.u[:] = eq.x.copy(), eq.u
    ctrl = None
    ratio = 1
    if control == 'margin':
        if cur is None:
            raise CircuitError([f'{circuit.name}: margin control needs the electro-hydraulic '
                                'pump (type pump)'])
        _margin_of(circuit)
        # A steady state at the current that feeds the loads: the controller starts from a
        # plant at rest, as a node's controller does after the simulator's start.
        u0 = eq.u.copy()
        u0[circuit.input_index(cur)] = start_current(circuit, eq)
        eq = equilibrium(circuit, u0, x0=eq.x)
        sim.x, sim.u[:] = eq.x.copy(), eq.u
        ctrl = make_controller(cfg)
        ratio = int(round(cfg.period / dt))
        if ratio < 1 or abs(ratio * dt - cfg.period) > 1e-9:
            raise InputError(f'controller period {cfg.period:g} s is not a multiple of '
                             f'{dt:g} s')
    i_cur = circuit.input_index(cur) if ctrl is not None else None
    index = {k: circuit.signal_index(v) for k, v in circuit.measured().items()}
    profile = profile or SensorProfile.from_config(SensorConfig())
    bank = SensorBank(profile, dt, like={'ls_pressure': 'line_pressure'})
    if ctrl is not None:
        y = sim.outputs()
        ctrl.reset(float(sim.u[i_cur]), bank.measure({k: float(y[i]) for k, i in index.items()}))
    Y = np.empty((n + 1, circuit.n_signals))
    Uo = np.empty((n + 1, len(circuit.inputs)))
    t_ctrl, meas_log = [], {}
    for j in range(-n0, n + 1):
        row = U[j + n0]
        if ctrl is not None:
            row = row.copy()
            row[i_cur] = sim.u[i_cur]
        sim.u[:] = row
        y = sim.outputs()
        if ctrl is not None and (j + n0) % ratio == 0:
            meas = bank.measure({k: float(y[i]) for k, i in index.items()})
            sim.set_input(cur, ctrl.update(j * dt, cfg.period, meas))
            if j >= 0:
                t_ctrl.append(j * dt)
                for k, v in meas.items():
                    meas_log.setdefault(k, []).append(v)
        if j >= 0:
            Y[j] = y
            Uo[j] = sim.u
        if j < n:
            sim.step()
    violations = invariants.check(circuit, t, Y, Uo)
    if violations and invariants.strict():
        raise invariants.InvariantError(violations, circuit.name)
    return CircuitRun(circuit, t, Y, Uo, control, ctrl.algorithm if ctrl else None, margin,
                      np.array(t_ctrl), {k: np.array(v) for k, v in meas_log.items()},
                      {'config': cfg if ctrl is not None else None, 'violations': violations})
