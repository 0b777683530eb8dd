"""The whole of eq. 16 from recordings (``hydropump fit --matrix``).

Each element of the transfer matrix from ``[i_s, p_u]`` to ``[p_l, q_l]`` is fitted, as a
continuous-time model with its measurement delay, to the step responses a recording holds
(each step from the steady state the one before left: the dwell must be several time
constants), by output-error least squares (scipy) with one level per step:

- **G21 growing flow** (current up): ``G0 / (1 + tau s)``, eq. 19;
- **G21 falling flow** (current down): ``G0 (1 + tau_z s) / (1 + tau s)``, the zero of
  eq. 17 (``b_p + s S_a``: ``tau_z = S_a / b_p``) and its own time constant;
- **G11** (current to line pressure): ``G0 / ((1 + tau s)(1 + tau_l s))``, the line pole;
- **G12** (load pressure to line pressure, from load-pressure steps at a held current):
  ``G0 / (1 + tau_l s)``.

Standard errors are Newey-West corrected for correlated residuals
(:func:`.diagnostics.covariance`). :func:`linear_elements` gives the same figures from the
linearisation of a params file (:func:`hydropump_sim.linear.transfer_matrix`), for
comparison. Gains are SI: m^3/s per A, Pa per A, Pa per Pa. Nothing here imports ROS.
"""

from __future__ import annotations

from dataclasses import dataclass, field
import math

import numpy as np

from .diagnostics import covariance
from .errors import FitError

ELEMENTS = {
    'G21_up': ('solenoid_current', 'line_flow', +1, ('G0', 'tau', 'td')),
    'G21_down': ('solenoid_current', 'line_flow', -1, ('G0', 'tau', 'tau_z', 'td')),
    'G12': ('load_pressure', 'line_pressure', 0, ('G0', 'tau_l', 'td')),
    'G11': ('solenoid_current', 'line_pressure', +1, ('G0', 'tau', 'tau_l', 'td')),
}
DWELL_MIN = 0.05   # s: a step needs at least this long before the next one
# What an element takes from another one fitted before it: falling flow shares the measurement
# delay of growing flow (one sensor chain; the zero of eq. 17 would otherwise trade against
# it), and G11 the line pole of G12 (one pole of the plant, which the load-pressure steps
# isolate; current steps mix it with the spool and plate lags).
FIXED_FROM = {'G21_down': {'td': 'G21_up (one measurement path)'},
              'G11': {'tau_l': 'G12 (the line pole)'}}


def step_response(kind: str, th: dict, t: np.ndarray) -> np.ndarray:
    """Unit-step response of an element's model at ``t`` (zero before ``t = 0``)."""
    t = np.maximum(t, 0.0)
    on = (t > 0).astype(float)
    if kind == 'G21_up':
        return on * (1.0 - np.exp(-t / th['tau']))
    if kind == 'G21_down':
        return on * (1.0 - (1.0 - th['tau_z'] / th['tau']) * np.exp(-t / th['tau']))
    if kind == 'G11':
        a, b = th['tau'], th['tau_l']
        if abs(a - b) < 1e-9 * a:
            b = a * (1 + 1e-6)
        return on * (1.0 - (a * np.exp(-t / a) - b * np.exp(-t / b)) / (a - b))
    return on * (1.0 - np.exp(-t / th['tau_l']))


@dataclass
class Element:
    name: str
    values: dict[str, float]
    stderr: dict[str, float]
    n_steps: int
    fit_percent: float
    notes: list[str] = field(default_factory=list)

    def to_dict(self) -> dict:
        return {'values': self.values, 'stderr': self.stderr, 'n_steps': self.n_steps,
                'fit_percent': self.fit_percent, 'notes': self.notes}


def held_levels(u: np.ndarray, dt: float) -> np.ndarray:
    """A measured staircase as held levels: the steps that stand out of the noise (ten noise
    standard deviations), each level the median between them (a clean command comes back
    as it is)."""
    from .calibrate.data import noise_level
    from .signals import find_steps
    idx, size = find_steps(u, dt)
    sigma = noise_level(u)
    keep = np.abs(size) > max(10.0 * sigma, 1e-9 * float(np.max(np.abs(u))))
    bounds = [0, *sorted(int(i) for i in idx[keep]), u.size]
    out = np.empty_like(u, dtype=float)
    for a, b in zip(bounds[:-1], bounds[1:]):
        if b > a:
            out[a:b] = np.median(u[a:b])
    return out


def _segments(u: np.ndarray, dt: float, sign: int):
    """``(start, stop, size)`` per step of the held input ``u`` (``sign`` +1 up, -1 down,
    0 both), each up to the next step."""
    du = np.diff(u)
    span = float(np.ptp(u)) or 1.0
    steps = np.flatnonzero(np.abs(du) > 1e-3 * span) + 1
    out = []
    bounds = list(steps) + [u.size]
    for k, s in enumerate(steps):
        stop = bounds[k + 1]
        size = float(u[s] - u[s - 1])
        if (stop - s) * dt < DWELL_MIN or (sign and np.sign(size) != sign):
            continue
        out.append((int(s), int(stop), size))
    return out


def fit_element(kind: str, records, dt: float, *, td_max: float = 0.25,
                fixed: dict[str, float] | None = None) -> Element:
    """Fit one element to the steps of each ``(u, y)`` of ``records`` (the input held, SI;
    the output, SI) (see the module); ``fixed`` holds values taken from other elements."""
    from scipy.optimize import least_squares
    _, _, sign, names = ELEMENTS[kind]
    fixed = dict(fixed or {})
    names = tuple(n for n in names if n not in fixed)
    segs, t_of, y_of = [], [], []
    for u, y in records:
        for s, stop, size in _segments(u, dt, sign):
            segs.append((s, stop, size))
            # The window starts one sample before the step: the level is fitted from data.
            t_of.append(np.arange(-1, stop - s) * dt)
            y_of.append(y[s - 1:stop])
    if not segs:
        which = {1: 'rising ', -1: 'falling ', 0: ''}[sign]
        raise FitError(f'{kind}: no {which}step of the input with a dwell of at least '
                       f'{DWELL_MIN:g} s in the recordings')
    ok_of = [np.isfinite(v) for v in y_of]
    gain0 = np.median([(v[ok][-20:].mean() - v[ok][:1].mean()) / size for v, ok, (_, _, size)
                       in zip(y_of, ok_of, segs) if ok.sum() > 20]) if segs else 1.0
    span = max(float((stop - s) * dt) for s, stop, _ in segs)
    x0 = {'G0': gain0, 'tau': min(0.05, span / 4), 'tau_z': 0.005, 'tau_l': 0.004,
          'td': 0.01}
    lo = {'G0': -np.inf, 'tau': dt / 4, 'tau_z': 0.0, 'tau_l': dt / 20, 'td': 0.0}
    hi = {'G0': np.inf, 'tau': span, 'tau_z': span, 'tau_l': span / 4, 'td': td_max}
    if x0['G0'] == 0 or not math.isfinite(x0['G0']):
        raise FitError(f'{kind}: the output does not move with the input')
    scale_y = float(np.nanstd(y)) or 1.0
    n = len(names)

    def split(x):
        th = dict(zip(names, x[:n]))
        th.update(fixed)
        return th, x[n:]

    def resid(x):
        th, levels = split(x)
        out = []
        for (_, _, size), t, v, ok, y0 in zip(segs, t_of, y_of, ok_of, levels):
            m = y0 + th['G0'] * size * step_response(kind, th, t - th['td'])
            out.append(((m - v) / scale_y)[ok])
        return np.concatenate(out)

    levels0 = [float(v[ok][0]) for v, ok in zip(y_of, ok_of)]
    x_start = np.array([x0[k] for k in names] + levels0)
    lb = np.array([lo[k] for k in names] + [-np.inf] * len(segs))
    ub = np.array([hi[k] for k in names] + [np.inf] * len(segs))
    best = None
    # A few delay starts: the delay's cost has local minima at whole dither periods.
    for td0 in ((0.0, 0.02, 0.05, 0.1) if 'td' in names else (0.0,)):
        if 'td' in names:
            x_start[names.index('td')] = min(td0, td_max)
        sol = least_squares(resid, np.clip(x_start, lb + 1e-12, ub - 1e-12), bounds=(lb, ub),
                            x_scale='jac', method='trf', max_nfev=200)
        if best is None or sol.cost < best.cost:
            best = sol
    th, _ = split(best.x)
    r = best.fun
    lens = [int(ok.sum()) for ok in ok_of]
    groups, k = [], 0
    for m in lens:
        groups.append(slice(k, k + m))
        k += m
    _, cov, _ = covariance(best.jac, r, groups)
    se = {nm: float(math.sqrt(max(cov[i, i], 0.0))) for i, nm in enumerate(names)}
    # Fit % of the step responses (the levels taken out).
    yy = np.concatenate([v[ok] for v, ok in zip(y_of, ok_of)])
    den = np.linalg.norm(yy - np.concatenate([np.full(m, lv) for m, lv in
                                              zip(lens, best.x[n:])]))
    fitp = float(100 * (1 - np.linalg.norm(r * scale_y) / den)) if den > 0 else math.nan
    notes = [f'{k} = {v:.6g} taken from {FIXED_FROM[kind][k]}' for k, v in fixed.items()]
    return Element(kind, {k: float(v) for k, v in th.items()}, se, len(segs), fitp, notes)


def fit_matrix(recordings, *, params=None) -> dict[str, Element]:
    """Every element the recordings can inform (current and load-pressure steps): pooled over
    recordings by fitting each element on the concatenated steps of all of them."""
    from .calibrate.data import experiment_from
    from .signals import load_default_params
    params = params or load_default_params()
    out: dict[str, Element] = {}
    missing = []
    for kind, (inp, outp, _, _) in ELEMENTS.items():
        records = []
        for rec in recordings:
            if outp not in rec:
                continue
            e = experiment_from(rec, params, signals=[outp])
            u = e.current if inp == 'solenoid_current' else e.load_pressure
            if u is None:
                continue
            u = held_levels(u, e.dt)
            # The other input held: a current element needs a constant load pressure, and
            # the load element a constant current.
            other = e.load_pressure if inp == 'solenoid_current' else e.current
            if other is not None and np.ptp(held_levels(other, e.dt)) > 0:
                continue
            records.append((u, e.measured[outp]))
        if not records:
            missing.append(kind)
            continue
        fixed = {k: out[src.split()[0]].values[k] for k, src in FIXED_FROM.get(kind, {}).items()
                 if src.split()[0] in out}
        try:
            out[kind] = fit_element(kind, records, recordings[0].dt, fixed=fixed)
        except FitError as exc:
            missing.append(f'{kind} ({exc.lines[0] if exc.lines else exc})')
    if not out:
        raise FitError('no element of eq. 16 can be fitted: the recordings need current steps '
                       'at a held load pressure (G21, G11) or load-pressure steps at a held '
                       f'current (G12); missing: {", ".join(missing)}')
    return out


def linear_elements(params, current: float | None = None) -> dict[str, dict[str, float]]:
    """The same elements from the linearisation of the fine model
    (:func:`hydropump_sim.linear.linearize`) at the equilibrium of ``current`` (absolute A),
    on each side of the pilot valve's kink: the gain, the dominant (slowest) pole, the line
    pole (the slowest other real pole) and, for falling flow, the zero of eq. 17 (the slowest
    real zero)."""
    import control

    from hydropump_sim.linear import linearize
    from hydropump_sim.trim import equilibrium
    eq = equilibrium(params, current)

    def element(lin, inp, outp):
        tf = control.ss2tf(lin.ss(inputs=[inp], outputs=[outp]))
        real = sorted(float(-1.0 / p.real) for p in tf.poles() if abs(p.imag) < 1e-6 * abs(p))
        zeros = sorted(float(-1.0 / z.real) for z in tf.zeros()
                       if z.real < 0 and abs(z.imag) < 1e-6 * abs(z))
        return float(np.real(control.dcgain(tf))), real, zeros

    out = {}
    for branch, kind in (('pos', 'G21_up'), ('neg', 'G21_down')):
        lin = linearize(params, eq, branch)
        g, taus, zeros = element(lin, 'i_s', 'q_l')
        out[kind] = {'G0': g, 'tau': taus[-1]}
        if kind == 'G21_down':
            out[kind]['tau_z'] = zeros[-1] if zeros else 0.0
        if branch == 'pos':
            g, taus, _ = element(lin, 'i_s', 'P_l')
            out['G11'] = {'G0': g, 'tau': taus[-1], 'tau_l': taus[-2]}
            out['G12'] = {'G0': element(lin, 'P_u', 'P_l')[0], 'tau_l': taus[-2]}
    return out
