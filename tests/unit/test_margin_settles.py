"""Margin control settles on every shipped load-sensing circuit, EMC and PI, with the pump
short of its flow and saturated (the loads asking more than it gives).

The truths are the definitions of the two regimes, not the controller's output:

- short of its flow: at a steady operating point (commands held, the cylinders inside their
  strokes) the margin ``P_l - P_LS`` rests at its set-point, with no limit cycle: its
  peak-to-peak ripple over the last second under 1 bar, its mean within 0.5 bar;
- saturated: the pump delivers its full flow ``V_p f_p`` (eq. 8 at full displacement,
  within 0.5 %), the margin whatever the loads leave of it, and no limit cycle either.

The runs go through the one closed-loop harness (the offline twin of the nodes), designed
for each circuit, ideal sensors, taking the circuit over at rest (the pump at zero
displacement, the valves open from the start); every run also proves the physical
invariants.
"""

import numpy as np
import pytest

from hydropump_ctrl.experiments.circuit_loop import run_circuit
from hydropump_sim.circuit import load_circuit

from ..conftest import ROOT

CIRCUITS = ROOT / 'config' / 'circuits'
# Operating points: each cylinder stays inside its stroke for the whole run (settle and
# the judged second), at the commands' flows.
CASES = {
    'fig1': ({'boom.command': 0.6, 'motor.command': 0.4, 'steering.command': 0.3},
             {'boom.command': 1.0, 'motor.command': 1.0, 'steering.command': 0.3}),
    'three_loads': ({'load1.command': 0.6, 'load2.command': 0.5},
                    {'load1.command': 1.0, 'load2.command': 1.0, 'load3.command': 1.0}),
    # Boom up alone (post-compensated: flow sharing); boom, arm in and bucket curl together,
    # more than the 420 L/min pump gives.
    'excavator': ({'boom.command': 0.6},
                  {'boom.command': 1.0, 'arm.command': 0.6, 'bucket.command': 0.6}),
}
# The PI climbs out of the loads' starvation at its integral rate: it takes longer.
SETTLE, JUDGED = {'emc': 2.5, 'pi': 4.0}, 1.0


# The cylinders start near their retracted ends, so that the runs stay inside the strokes.
START = {'fig1': {}, 'three_loads': {f'load{k}.cylinder.x0': 0.05 for k in (1, 2, 3)},
         'excavator': {f'{n}.cylinder.x0': 0.1 for n in ('boom', 'arm', 'bucket')}}


@pytest.fixture(scope='module', params=sorted(CASES))
def circuit(request):
    name = request.param
    return name, load_circuit(CIRCUITS / f'{name}.yaml', START[name])


@pytest.mark.parametrize('algorithm', ['emc', 'pi'])
def test_short_of_flow_the_margin_rests_at_its_set_point(circuit, algorithm):
    name, c = circuit
    run = run_circuit(c, JUDGED, CASES[name][0], algorithm=algorithm, margin=2.5e6,
                      settle=SETTLE[algorithm])
    margin = run['pump.P_l'] - run['node:ls']
    assert np.ptp(margin) < 1.0e5, (name, algorithm, np.ptp(margin))
    assert abs(np.mean(margin) - 2.5e6) < 0.5e5, np.mean(margin)
    assert run['pump.Q_p'].mean() < 0.95 * c.plant_params().Q_max  # short of its flow
    _inside_strokes(c, run, CASES[name][0])


def _inside_strokes(c, run, commands):
    """A steady operating point: no moving cylinder at an end of its stroke (or its
    cushion)."""
    for name, sig in c.loads().items():
        if 'position' in sig and commands.get(f'{name}.command'):
            stroke = c.signal_index(sig['position'])
            pos = run.y[:, stroke]
            L = next(pt.comp.params.stroke for pt in c.role('actuator')
                     if pt.comp.name == f'{name}.cylinder')
            assert 0.05 * L < pos.min() and pos.max() < 0.95 * L, (name, pos.min(), pos.max())


@pytest.mark.parametrize('algorithm', ['emc', 'pi'])
def test_saturated_the_pump_gives_its_full_flow_without_a_limit_cycle(circuit, algorithm):
    name, c = circuit
    run = run_circuit(c, JUDGED, CASES[name][1], algorithm=algorithm, margin=2.5e6,
                      settle=SETTLE[algorithm])
    plant = c.plant_params()
    full = plant.pump.V_p * plant.pump.f_p          # eq. 8 at full displacement
    assert run['pump.Q_p'].min() == pytest.approx(full, rel=5e-3), (name, algorithm)
    margin = run['pump.P_l'] - run['node:ls']
    assert margin.max() < 2.5e6                       # the loads took the margin
    assert np.ptp(margin) < 1.0e5, (name, algorithm, np.ptp(margin))
    _inside_strokes(c, run, CASES[name][1])
