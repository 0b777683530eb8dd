"""Start values in closed form: what the settled stairs and the steps of the recordings give
directly, before any simulation of the free parameters.

- ``line.mu_u`` from the load law of eq. 9 at rest: the flow a settled stair delivers is
  ``mu_u xi_u (P_l - P_u)^(1/gamma_u)``;
- ``actuator.P_a_bar`` from the force balance of eq. 6 at rest (``x_c = 0``, so eq. 1 gives
  ``K_a x_a = phi_s i_s``): ``P_a = P_a_bar - ((K_b + K_a) x_a + (P_l - P_l_bar) S_d) / S_a``;
- ``actuator.mu_a`` from the growing-flow time constant of the current steps (the
  :mod:`..matrix` fit of ``G21``) through eq. 14 with ``K_c`` kept (docs/reference.md I8):
  ``tau = S_a (1 + K_c/K_a) / (mu_a sqrt(P_a - P_T))``.

Each uses only settled stairs (or the steps) of the signals it needs, medians over them, and
the other parameters at the start's values; a value outside the schema's range, or one the
data cannot give, is left out. The calibration starts from these only where they lower the
cost. Nothing here imports ROS.
"""

from __future__ import annotations

from collections.abc import Sequence
import math

import numpy as np

from hydropump_sim.measure import FLOW_SIGNALS, LINE_FLOW_SIGNAL, LOAD_FLOW_SIGNAL
from hydropump_sim.params import Params
from hydropump_sim.schema import spec_map

from .data import Experiment

SETTLED = 0.4     # s after a change of the inputs before a stair counts as settled
WINDOW = 0.15     # s of the stair's end that are averaged
# The flows a stair's rest is read from: the load's own first (measure.LOAD_FLOW_SIGNAL).
FLOWS = (LOAD_FLOW_SIGNAL, *(f for f in FLOW_SIGNALS if f != LOAD_FLOW_SIGNAL))


def _stairs(exp: Experiment) -> list[slice]:
    """The settled ends of the stairs: sample ranges where the inputs have held for
    :data:`SETTLED` and go on holding for :data:`WINDOW`."""
    u = [exp.current] + ([exp.load_pressure] if exp.load_pressure is not None else [])
    change = np.zeros(exp.n, bool)
    for x in u:
        span = float(np.ptp(x)) or 1.0
        change[1:] |= np.abs(np.diff(x)) > 1e-3 * span
    edges = [0, *np.flatnonzero(change), exp.n]
    k_set, k_win = int(round(SETTLED / exp.dt)), max(int(round(WINDOW / exp.dt)), 3)
    return [slice(b - k_win, b) for a, b in zip(edges[:-1], edges[1:]) if b - a >= k_set + k_win]


def _mean(y, sl):
    v = y[sl]
    v = v[np.isfinite(v)]
    return float(np.mean(v)) if v.size else math.nan


def _load_pressure(exp: Experiment, params: Params, sl: slice) -> float:
    return params.line.P_u if exp.load_pressure is None else float(np.mean(exp.load_pressure[sl]))


def _mu_u(params: Params, exps: Sequence[Experiment]) -> float | None:
    ln = params.line
    vals = []
    for e in exps:
        flow = next((s for s in FLOWS if s in e.measured), None)
        if flow is None or 'line_pressure' not in e.measured:
            continue
        for sl in _stairs(e):
            q, p_l = _mean(e.measured[flow], sl), _mean(e.measured['line_pressure'], sl)
            dp = p_l - _load_pressure(e, params, sl)
            if math.isfinite(q) and dp > 10 * ln.dp_cr_u and p_l < params.relief.p_crack:
                vals.append(q / (ln.xi_u * dp ** (1.0 / ln.gamma_u)))
    return float(np.median(vals)) if vals else None


def _p_a_bar(params: Params, exps: Sequence[Experiment]) -> float | None:
    sp, ac, pl, ln = params.spool, params.actuator, params.plate, params.line
    vals = []
    for e in exps:
        if 'actuator_pressure' not in e.measured or 'line_pressure' not in e.measured:
            continue
        for sl in _stairs(e):
            x_a = sp.phi_s * (float(np.mean(e.current[sl])) - params.I_nominal) / sp.K_a
            if abs(x_a) >= 0.95 * params.x_a_stop:
                continue
            p_a, p_l = _mean(e.measured['actuator_pressure'], sl), \
                _mean(e.measured['line_pressure'], sl)
            vals.append(p_a + ((pl.K_b + sp.K_a) * x_a + (p_l - ln.P_l_bar) * pl.S_d) / ac.S_a)
    vals = [v for v in vals if math.isfinite(v)]
    return float(np.median(vals)) if vals else None


def _mu_a(params: Params, exps: Sequence[Experiment], p_a: float) -> float | None:
    from ..errors import FitError
    from ..matrix import fit_element, held_levels
    sp, ac = params.spool, params.actuator
    taus = []
    for e in exps:
        # The line's flow first (eq. 19's output: its lag is the time constant sought).
        flow = next((s for s in (LINE_FLOW_SIGNAL, *FLOW_SIGNALS) if s in e.measured), None)
        if flow is None or np.ptp(e.current) <= 0:
            continue
        y = e.measured[flow]
        if not np.isfinite(y).all():
            continue
        try:
            el = fit_element('G21_up', [(held_levels(e.current, e.dt), y)], e.dt)
        except (FitError, ValueError, np.linalg.LinAlgError):
            continue
        taus.append(el.values['tau'])
    dp = p_a - params.fluid.P_T
    if not taus or not dp > 0:
        return None
    tau = float(np.median(taus))
    return ac.S_a * (1.0 + sp.K_c / sp.K_a) / (tau * math.sqrt(dp))


def start_values(params: Params, free: Sequence[str], exps: Sequence[Experiment]
                 ) -> tuple[dict[str, float], list[str]]:
    """Closed-form start values of the free parameters the recordings give directly, and a
    few words on where each came from."""
    specs = spec_map(Params)
    out, why = {}, []

    def take(name: str, value: float | None, how: str) -> None:
        if value is None or not math.isfinite(value):
            return
        lo, hi = specs[name].range
        if lo < value < hi:
            out[name] = float(value)
            why.append(f'{name} from {how}')

    if 'line.mu_u' in free:
        take('line.mu_u', _mu_u(params, exps), 'the load law at rest (eq. 9)')
    p_a_bar = None
    if 'actuator.P_a_bar' in free:
        p_a_bar = _p_a_bar(params, exps)
        take('actuator.P_a_bar', p_a_bar, 'the force balance at rest (eq. 6)')
    if 'actuator.mu_a' in free:
        # The actuator pressure the steps ran at (eq. 14's P_a), else eq. 6's P_a_bar.
        measured = [e.measured['actuator_pressure'] for e in exps
                    if 'actuator_pressure' in e.measured]
        p_a = float(np.nanmedian(np.concatenate(measured))) if measured else \
            out.get('actuator.P_a_bar', params.actuator.P_a_bar)
        take('actuator.mu_a', _mu_a(params, exps, p_a), 'the growing-flow time constant '
             '(eq. 14)')
    return out, why
