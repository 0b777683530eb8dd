"""One run of a sweep (what a Dask worker executes) and its outputs.

A run builds the plant with the sampled values (and the parameters that follow them, see
:data:`.spec.RELATIONS`), simulates the experiment and computes the outputs. Any failure (a
value the schema refuses, an integration error, a fit that cannot be made) becomes the run's
``status = 'failed'`` with the reason, never an exception: the sweep goes on.

Step metrics of the line flow ``q_l`` at the experiment's first current step ``t_s``, against
the flow just before it (``y0``) and the mean of the last 5 % of the window up to the next
step or the end (``y1``):

- ``step_rise``: time from 10 % to 90 % of ``y1 - y0`` [s];
- ``step_overshoot``: largest excursion beyond ``y1`` in % of ``|y1 - y0|`` (0 if none);
- ``step_settling``: from ``t_s`` to the last time the flow is outside ``y1 ± 2 %`` [s].
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

STATUS_OK, STATUS_FAILED = 'ok', 'failed'


def step_metrics(t: np.ndarray, y: np.ndarray, t_step: float, t_end: float) -> dict:
    """Rise time, overshoot and 2 % settling time of ``y`` after a step at ``t_step``."""
    k0 = max(int(np.searchsorted(t, t_step)) - 1, 0)
    win = (t >= t_step) & (t <= t_end)
    tw, yw = t[win], y[win]
    y0 = y[k0]
    tail = max(int(0.05 * tw.size), 1)
    y1 = float(np.mean(yw[-tail:]))
    span = y1 - y0
    if tw.size < 3 or span == 0.0:
        raise ValueError('the flow does not move after the step')
    frac = (yw - y0) / span
    t10 = _first_crossing(tw, frac, 0.1)
    t90 = _first_crossing(tw, frac, 0.9)
    overshoot = max(0.0, float(np.max(frac)) - 1.0) * 100.0
    outside = np.flatnonzero(np.abs(frac - 1.0) > 0.02)
    settle = (tw[min(outside[-1] + 1, tw.size - 1)] - t_step) if outside.size else 0.0
    return {'step_rise': t90 - t10, 'step_overshoot': overshoot,
            'step_settling': float(settle)}


def _first_crossing(t: np.ndarray, frac: np.ndarray, level: float) -> float:
    k = int(np.argmax(frac >= level))
    if frac[k] < level:
        raise ValueError(f'the flow never reaches {level:.0%} of its step')
    if k == 0:
        return float(t[0])
    return float(t[k - 1] + (level - frac[k - 1]) / (frac[k] - frac[k - 1])
                 * (t[k] - t[k - 1]))


def _plant(base, names, values, relations):
    """The run's plant: the sampled values, then the parameters that follow them."""
    flat = base.flat()
    new = dict(zip(names, (float(v) for v in values)))
    merged = {**flat, **new}
    for follower, inputs, fn in relations:
        new[follower] = float(fn(*(merged[n] for n in inputs)))
    return base.replace(new)


def outputs_of(res, experiment, nominal, outputs) -> dict:
    """The output columns of one simulated run."""
    out: dict[str, float] = {}
    for kind, sig in outputs:
        if kind == 'fopdt':
            from ..ident import fit_recording, Recording
            rec = Recording(res.t, {'solenoid_current': res.I_s, 'line_flow': res.q_l},
                            name='run')
            # The nominal plant normalises, as an engineer normalises a bench record.
            fit = fit_recording(rec, params=nominal)
            out.update(fopdt_G0=fit.G0, fopdt_tau=fit.tau, fopdt_td=fit.td)
        elif kind == 'step':
            steps = experiment.step_times
            if not steps:
                raise ValueError('step metrics need a current step in the experiment')
            end = steps[1] if len(steps) > 1 else experiment.duration
            out.update(step_metrics(res.t, res.q_l, steps[0], end))
        elif kind == 'peak':
            out[f'peak_{sig}'] = float(np.max(getattr(res, sig)))
        else:
            out[f'final_{sig}'] = float(getattr(res, sig)[-1])
    return out


def run_one(run_id: int, values, ctx: dict) -> dict[str, Any]:
    """Run ``run_id`` with the sampled ``values``; ``ctx`` holds the nominal plant, the
    experiment, the outputs and the relations. Never raises for a bad run."""
    t0 = time.perf_counter()
    row: dict[str, Any] = {'run_id': int(run_id), 'status': STATUS_OK, 'reason': ''}
    try:
        from hydropump_sim import simulate
        plant = _plant(ctx['plant'], ctx['names'], values, ctx['relations'])
        ex = ctx['experiment']
        res = simulate(plant, ex.duration, model=ex.model, dt_out=ex.dt_out,
                       current=ex.inputs.get('current'),
                       load_pressure=ex.inputs.get('load_pressure'),
                       aperture=ex.inputs.get('aperture'),
                       shaft_speed=ex.inputs.get('shaft_speed'))
        row.update(outputs_of(res, ex, ctx['plant'], ctx['outputs']))
    except Exception as exc:  # noqa: BLE001 - a failed run is data, recorded with its reason
        lines = getattr(exc, 'lines', None) or [str(exc) or type(exc).__name__]
        row.update(status=STATUS_FAILED, reason=f'{type(exc).__name__}: ' + '; '.join(lines))
    row['wall_s'] = time.perf_counter() - t0
    return row


def run_batch(batch: list, ctx: dict) -> list[dict]:
    """Several runs in one task: ``[(run_id, values), ...]``."""
    return [run_one(i, v, ctx) for i, v in batch]
