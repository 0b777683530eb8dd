"""The demo campaign's pure side: its experiments, the figures of a closed-loop run read from
a recording, the tables and the HTML page (the graph itself runs in tests/e2e)."""

import math

import numpy as np
import pytest

from hydropump_ctrl.demo import campaign, report
from hydropump_ctrl.experiments.closed_loop import disturbance_figures
from hydropump_ctrl.ident import PAPER, Recording
from hydropump_sim.model import pump_flow

P_ATM = 1.013e5


def _recording(t, **signals):
    # The grid starts 2 s into simulation time, as a run's recording may.
    held = {'solenoid_current': np.full(t.size, 0.5), 'line_flow': np.zeros(t.size)}
    return Recording(t - 2.0, {**held, **signals}, name='run', t0_ns=2_000_000_000)


def _first_order(t, t_step, y0, y1, tau):
    return np.where(t < t_step, y0, y1 + (y0 - y1) * np.exp(-(t - t_step) / tau))


def test_experiments_name_their_runs_and_bags(params, tmp_path):
    idents = campaign.identification_experiments(params, 9, dwell=0.5, levels=4)
    assert [e.name for e in idents] == [f'ident_{i}' for i in range(1, 10)]
    assert len({e.sim['sensors.seed'] for e in idents}) == 9
    # The paper's protocol: one operating point (the nominal load), growing flow only, levels
    # and step sizes differing, inside the 0..100 % regulating range.
    assert {e.sim['line.P_u'] for e in idents} == {params.line.P_u}
    assert len({(e.ctrl['excitation.levels_min'], e.ctrl['excitation.levels_max'])
                for e in idents}) == 9
    assert all(e.ctrl['excitation.direction'] == 'up' for e in idents)
    assert all(0 < e.ctrl['excitation.levels_min'] < e.ctrl['excitation.levels_max'] < 100
               for e in idents)
    assert all(e.duration == 2.0 and e.topics == campaign.IDENT_TOPICS for e in idents)
    loops = campaign.closed_loop_experiments(params, ('emc',))
    assert [e.name for e in loops] == ['emc_flow_step', 'emc_aperture_step', 'emc_margin_step']
    assert loops[1].sim['line.xi_u'] == 0.5
    assert loops[1].events == [(0.5, 'simulator', {'line.xi_u': 0.4})]
    assert all(e.preroll > 0 for e in loops)
    assert loops[0].bag(tmp_path) == tmp_path / 'emc_flow_step'


@pytest.mark.parametrize('flow_map', ['paper', 'consistent'])
def test_flow_step_figures_use_eq_8_as_the_model_computes_it(params, flow_map):
    # The full stroke of the consistent map needs a larger actuator chamber at rest.
    p = params.replace({'pump.flow_map': flow_map, 'actuator.V_a0': 2.0e-5})
    exp = campaign.closed_loop_experiments(p, ('emc',))[0]
    q0, q1 = exp.ctrl['reference.flow'], exp.events[0][2]['reference.flow']
    t = np.arange(1501) * 1e-3 + 2.0
    q = _first_order(t, 2.5, q0, q1, 0.03)
    # The plate position whose eq. 8 flow is q, in this flow-map reading.
    grid = np.linspace(-p.x_a_stop, p.x_a_stop, 4001)
    x_a = np.interp(q, pump_flow(p, grid), grid)
    f = campaign.loop_figures(p, exp, _recording(t, actuator_position=x_a), t_step=2.5)
    assert f['unit'] == '% FS' and f['iae_unit'] == '% FS s'
    # A first-order step of 30 ms: rise (10-90 %) 2.2 tau, no overshoot.
    assert f['rise_s'] == pytest.approx(2.2 * 0.03, abs=3e-3)
    assert f['overshoot_pct'] < 0.1
    ty, y = f['y']
    assert ty[0] >= 2.4 - 1e-9
    assert y[-1] == pytest.approx(70.0, abs=0.05)


def test_margin_disturbance_figures_are_those_of_the_harness(params):
    exp = campaign.closed_loop_experiments(params, ('pi',))[1]
    dp = exp.ctrl['reference.margin']
    t = np.arange(1501) * 1e-3 + 2.0
    # A dip of 2 bar at the aperture step, back with 50 ms.
    margin = dp - 2.0e5 * np.where(t < 2.5, 0.0, np.exp(-(t - 2.5) / 0.05))
    p_u = 1.0e7 + P_ATM
    rec = _recording(t, line_pressure=p_u + margin, load_pressure=np.full(t.size, p_u))
    f = campaign.loop_figures(params, exp, rec, t_step=2.5)
    assert set(f) == {'peak_bar', 'recovery_s', 'iae', 'iae_unit', 'y', 'unit',
                      'pre_step_error_pct'}
    # On its set-point until the step: only the centred 20 ms average lets the last 10 ms
    # before the step see the dip (2 bar x 10 ms / 0.3 s of a 25 bar margin: 0.07 % at most).
    assert f['pre_step_error_pct'] < 0.08
    ty, y = f['y']
    d = disturbance_figures(ty, y * 1e5, 2.5, dp, 1.0e5)
    assert f['peak_bar'] == pytest.approx(-d.peak * 1e-5)
    assert f['recovery_s'] == d.recovery and f['iae'] == pytest.approx(d.iae * 1e-5)
    # The 20 ms average blunts the 2 bar dip but keeps its area and its recovery after
    # ln(2) tau within half the window.
    assert 1.5 <= f['peak_bar'] < 2.0
    assert f['recovery_s'] == pytest.approx(0.05 * math.log(2.0), abs=0.011)
    assert f['iae'] == pytest.approx(2.0 * 0.05, rel=0.05)


class _Pooled:
    mean = {'G0': 99.8, 'tau': 0.0951, 'td': 0.0572}
    std = {'G0': 0.4, 'tau': 0.0012, 'td': 0.0008}


class _Ident:
    pooled = _Pooled()
    sets = [object()] * 3


TRUTH = {'G0': 100.1, 'tau': 0.0944, 'td_plant': 0.0021, 'td_configured': 0.055,
         'tau_nominal': 0.1004}


def test_tables_put_the_paper_beside_the_run():
    rows = report.identification_rows(_Ident(), TRUTH)
    assert rows[0] == ['paper (9 sets)', f'{PAPER["G0"][0]:.1f} ± {PAPER["G0"][1]:.1f}',
                       '100.0 ± 2.0', '55.0 ± 5.5']
    assert rows[1][1:] == ['99.80 ± 0.40', '95.1 ± 1.2', '57.2 ± 0.8']
    assert rows[4][2] == '100.4'
    head, loop_rows = report.loop_table({
        'emc_flow_step': {'rise_s': 0.1234, 'overshoot_pct': 1.0, 'settling_s': math.inf,
                          'iae': 1.5, 'iae_unit': '% FS s'}})
    assert loop_rows == [['emc_flow_step', '0.123', '1', 'never', '', '', '1.5 % FS s']]
    text = report.text_table(head, loop_rows).splitlines()
    assert len(text) == 3 and set(text[1]) <= {'-', ' '}
    assert len({len(line) for line in text}) == 1


def test_summary_leaves_out_the_traces_and_the_page_stands_alone(tmp_path):
    loops = {'emc_margin_step': {'rise_s': 0.1, 'y': (np.zeros(2), np.ones(2))}}
    stages = {'identification': campaign.stage_times(10.0, 36.0, 1.0),
              'total': campaign.stage_times(20.0, 36.0, 4.0)}
    s = report.summary(_Ident(), TRUTH, loops, stages)
    assert s['wall_time_s'] == {'identification': 10.0, 'total': 20.0}
    # The stage table: simulated and wall time, and the overhead as a share of the wall.
    assert report.stage_rows(stages) == [['identification', '36', '10.0', '10'],
                                         ['total', '36', '20.0', '20']]
    assert s['closed_loop'] == {'emc_margin_step': {'rise_s': 0.1}}
    assert s['identification']['sets'] == 3 and s['plant'] == TRUTH
    page = report.write_html(tmp_path, [('A & B', '<p>x</p>')])
    text = page.read_text()
    assert page == tmp_path / 'report.html'
    assert '<h2>A &amp; B</h2><p>x</p>' in text and text.endswith('</html>')
