"""A circuit in closed loop, without ROS: the circuit stepped at 1 kHz, the bench's sensors,
and the pump under one of three controls, as the simulator and controller nodes run it:

- ``margin`` (the default): the electronic load-sensing control, EMC or PI in margin mode,
  regulating ``P_l - P_LS`` against the highest load;
- ``open``: the pump's current as scheduled (or held);
- ``hydromechanical``: the classic load-sensing compensator on the pump instead of the
  solenoid (the ``ls_pump`` component), for comparison.

The controller's embedded model is the pump's (``config/controller.yaml`` beside the
circuit's plant file, or designed from the plant) with the line capacitance the circuit
presents at the pump's outlet (:func:`hydropump_sim.reduction.line_capacitance`):
the simplified circuit model the controller needs.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
import dataclasses
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from hydropump_sim.circuit import Circuit, CircuitError
from hydropump_sim.errors import InputError
from hydropump_sim.inputs import Signal
from hydropump_sim.reduction import line_capacitance, with_fidelity
from hydropump_sim.sensors import SensorConfig, SensorProfile
from hydropump_sim.steady import equilibrium

from ..control import ControllerConfig, load_config, make_controller
from ..control.design import pi_margin_compensated_tuning
from .harness import Event, LoopRun, run_loop

CONTROLS = ('margin', 'open', 'hydromechanical')
#: The hydromechanical compensator's default margin [Pa] without a controller configuration.
MARGIN = 2.0e6


@dataclass
class CircuitRun(LoopRun):
    """One run (:class:`.harness.LoopRun`) with the control it ran under."""

    control: str = 'open'
    algorithm: str | None = None
    margin: float | None = None
    info: dict = field(default_factory=dict)

    @property
    def circuit(self) -> Circuit:
        return self.model


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


def at_rest(circuit: Circuit, u: np.ndarray | None = None) -> np.ndarray:
    """The inputs ``u`` (default the circuit's) with an electro-hydraulic pump at zero
    displacement: where a margin controller takes a circuit over from, rather than a pump
    at its nominal current pumping into closed sections until its cut-off or relief."""
    u = (circuit.u0 if u is None else u).copy()
    if circuit.electric_pump():
        u[circuit.input_index(f'{circuit.pump_name()}.current')] = \
            circuit.plant_params().current_range[0]
    return u


def controller_config(circuit: Circuit, eq=None, config: ControllerConfig | None = None
                      ) -> ControllerConfig:
    """The controller for a circuit: ``config`` (default the one ``hydropump design
    --circuit`` writes for it, ``controller_<circuit>.yaml``, or ``controller.yaml``, beside
    the circuit's file or in its folder's parent, if it was made for the circuit's pump, else
    designed from the plant) with the line capacitance the circuit presents at the pump's
    outlet."""
    pump = circuit.pump()
    plant = pump.comp.params.plant
    if config is None:
        src = Path(circuit.source)
        found = None
        own = f'controller_{src.stem}.yaml'
        for cand in (src.parent / own, src.parent.parent / own,
                     src.parent / 'controller.yaml', src.parent.parent / 'controller.yaml'):
            if cand.is_file():
                found = cand
                break
        if found is not None:
            config = load_config(found, current_limits=plant.I_limits)
        # A configuration made for another pump (its full flow not this one's) is not this
        # pump's: design one from its plant.
        if config is None or abs(config.model.Q_max / plant.Q_max - 1.0) > 0.01:
            from ..control.design import design_config
            config = design_config(plant)
    eq = equilibrium(circuit, at_rest(circuit)) if eq is None else eq
    node = pump.comp.ports['out'][0]
    values = {'model.C_l': line_capacitance(circuit, eq, node)}
    compensators = circuit.role('compensator')
    margin = config.reference.margin
    # Post compensators (flow sharing) leave the metering edges the margin less their
    # spring: their loads take more as the margin grows, as orifices do (eq. 9, the load's
    # conductance estimated); pre compensators hold a drop of their own, and the line is
    # an integrator of what the pump gives beyond their flow.
    sharing = compensators and all(
        pt.comp.metering_drop(2.0 * margin) > pt.comp.metering_drop(margin)
        for pt in compensators)
    if 'ls_pressure' in circuit.measured() and sharing:
        values['controller.mode'] = 'margin'  # what a load-sensing circuit's pump runs
        values['model.load_law'] = 'orifice'
    elif 'ls_pressure' in circuit.measured():
        # Compensated sections: the line an integrator for EMC's model and PI's tuning,
        # with the relief valve at the pump's outlet (the lowest cracking) in EMC's model.
        values['model.load_law'] = 'compensated'
        values['controller.mode'] = 'margin'  # what a load-sensing circuit's pump runs
        # The compensators' setting (the highest): below it the loads starve.
        settings = [pt.comp.metering_drop(margin) for pt in compensators]
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
                settle: float | None = None, dt: float = 1.0e-3,
                events: Sequence[Event] = (), fidelity: str = 'fine',
                bandwidth: float = 0.0) -> CircuitRun:
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
    events : sequence of Event
        Inputs held from their time on (an operator's duty cycle), and controller events.
    fidelity, bandwidth : str, float
        The circuit run: ``fine``, or section IV's ``simplified`` one at ``bandwidth`` [Hz]
        (0: margin control's, else section IV's); see
        :func:`hydropump_sim.reduction.with_fidelity`. ``info['fidelity']`` says which ran.
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
    # The controller is designed for the machine (the fine circuit); the simplified circuit
    # leaves out only what lies beyond its bandwidth.
    circuit, fid = with_fidelity(circuit, fidelity, bandwidth,
                                 cfg.bandwidth('margin') if control == 'margin' else None)
    ctrl, start, x0 = None, None, None
    if control == 'margin':
        if not circuit.electric_pump():
            raise CircuitError([f'{circuit.name}: margin control needs the electro-hydraulic '
                                'pump (type pump)'])
        _margin_of(circuit)
        # A steady state at the current that feeds the loads: the controller starts from a
        # plant at rest, as a node's controller does after the simulator's start. Found
        # from the circuit at rest (the pump at zero displacement), through the flow the
        # loads take at the pump's nominal current (a short march at most).
        u0, _ = circuit.input_table(np.zeros(1), inputs, dt)
        rest = equilibrium(circuit, at_rest(circuit, u0[0]))
        nominal = equilibrium(circuit, u0[0], x0=rest.x, horizon=2.0, strict=False)
        start = {f'{circuit.pump_name()}.current': start_current(circuit, nominal)}
        x0 = nominal.x
        ctrl = make_controller(cfg)
    run = run_loop(circuit, duration, controller=ctrl, inputs=inputs,
                   profile=profile or SensorProfile.from_config(SensorConfig()), settle=settle,
                   dt=dt, start=start, x0=x0, events=events)
    return CircuitRun(run.model, run.t, run.y, run.u, run.command, run.t_ctrl, run.state,
                      run.meas, run.mode, run.violations, control,
                      ctrl.algorithm if ctrl else None, margin,
                      {'config': cfg if ctrl is not None else None,
                       'violations': run.violations, 'fidelity': fid})
