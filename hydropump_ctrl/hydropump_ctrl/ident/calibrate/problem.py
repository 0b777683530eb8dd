"""The problem: weighted residuals of every experiment and their Jacobian in the search
coordinates, with the measurement delays and offsets solved inside (variable projection).

- **Free parameters** are searched in log coordinates (``z = log theta``: relative
  sensitivities; scaled linearly where the schema's range reaches zero), bounded by the
  schema's ranges; ties of the schema are kept (:data:`.engine.DERIVED`).
- **Residuals**: ``(model - measured) / sigma`` per experiment and signal, where the model's
  signal is delayed by the signal's measurement delay (fractional, by cubic interpolation:
  third-order accurate, so a delay between samples is found to a small fraction of a
  sample) and shifted by its offset where asked.
- **Nuisance parameters** (a delay per signal, shared by the recordings of one bench or with
  ``per_bag`` per recording, and optional offsets) are solved for at every evaluation by a
  bounded 1-D search each; their directions are projected out of the plant Jacobian
  (Kaufman's approximation), so the outer least squares sees only the plant parameters.
- **Priors** (optional, per parameter): a Gaussian in log coordinates, ``log theta ~
  N(log theta_p, rel^2)``, appended as one residual row each, as ``nlgreyest`` and Parameter
  Estimator users add them when the data leave a direction weak.

Nothing here imports ROS.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
import math

import numpy as np

from hydropump_sim.errors import HydropumpError
from hydropump_sim.params import Params
from hydropump_sim.schema import spec_map, unknown_key_line

from .engine import DERIVED, Engine

# A signal may also lead the recorded current by a few samples: a bench that stamps its
# current a sample late (or its measurements early) has measurements ahead of their cause.
LEAD_SAMPLES = 3
DELAY_MAX = 0.25    # s, the largest measurement delay fitted

# Parameters that are not in the equations, and the operating-point inputs a bag carries.
NOT_IN_MODEL = {'fluid.nu': 'it documents dp_cr and is not in the equations',
                'pump.l_d': 'it is information only (eq. 5), not in the equations'}
FROM_BAG = {'line.P_u': 'load_pressure'}


def check_free(base: Params, free: Sequence[str], recorded: Sequence[str] = ()) -> list[str]:
    """One line per free parameter that cannot be freed (unknown, derived, not a number, not
    in the model, an input the recordings carry); empty when all can."""
    specs = spec_map(Params)
    errors = []
    if not free:
        return ['no free parameter: name at least one with --free (e.g. actuator.mu_a)']
    seen = set()
    for name in free:
        if name in seen:
            errors.append(f'{name} is given twice')
            continue
        seen.add(name)
        s = specs.get(name)
        if s is None:
            errors.append(unknown_key_line(name, specs, 'plant parameter'))
        elif name in DERIVED:
            sources, rel, _ = DERIVED[name]
            primary = [x for x in sources if x != 'fluid.rho'] or list(sources)
            errors.append(f'{name} is derived from {" and ".join(sources)} ({rel}): free '
                          f'{" or ".join(primary)} instead')
        elif s.type is not float:
            errors.append(f'{name} is a {s.type.__name__}, not a number: it cannot be fitted')
        elif name in NOT_IN_MODEL:
            errors.append(f'{name} cannot be informed by any data: {NOT_IN_MODEL[name]}')
        elif name in FROM_BAG and FROM_BAG[name] in recorded:
            errors.append(f'{name} is an input: the recordings carry it as '
                          f'{FROM_BAG[name]}')
    return errors


@dataclass(frozen=True)
class Prior:
    """A Gaussian prior on a free parameter in log coordinates: ``log theta`` has mean
    ``log value`` and standard deviation ``log(1 + rel)`` (about ``rel``)."""

    name: str
    value: float
    rel: float

    @property
    def text(self) -> str:
        return f'{self.name} = {self.value:.6g} +- {100 * self.rel:.3g} % (prior)'


def parse_prior(text: str) -> Prior:
    """``NAME=VALUE+-REL`` (``REL`` a fraction or a percentage: ``0.05`` or ``5%``; ``±`` also
    taken) -> :class:`Prior`; ``ValueError`` with one line otherwise."""
    form = 'expected NAME=VALUE+-REL, e.g. line.V_l=5e-4+-10%'
    name, eq, rest = text.partition('=')
    rest = rest.replace('±', '+-')
    value, pm, rel = rest.partition('+-')
    if not (eq and pm and name.strip()):
        raise ValueError(f'--prior {text}: {form}')
    try:
        v = float(value)
        r = float(rel.strip().rstrip('%')) / (100.0 if rel.strip().endswith('%') else 1.0)
    except ValueError:
        raise ValueError(f'--prior {text}: {form}') from None
    if not (math.isfinite(v) and v > 0):
        raise ValueError(f'--prior {text}: the value must be a positive number (log '
                         'coordinates)')
    if not (math.isfinite(r) and 0 < r < 10):
        raise ValueError(f'--prior {text}: the relative standard deviation must be in '
                         '(0, 10) (0.05 or 5% for 5 %)')
    return Prior(name.strip(), v, r)


@dataclass(frozen=True)
class Coordinates:
    """Free parameters <-> the search vector ``z``: ``log theta`` where the schema's range is
    positive, ``theta / scale`` where it reaches zero."""

    names: tuple[str, ...]
    log: np.ndarray
    scale: np.ndarray
    lo: np.ndarray
    hi: np.ndarray

    @classmethod
    def of(cls, base: Params, free: Sequence[str]) -> Coordinates:
        specs = spec_map(Params)
        flat = base.flat()
        lo, hi = (np.array([specs[n].range[k] for n in free], float) for k in (0, 1))
        log = lo > 0
        v = np.array([float(flat[n]) for n in free])
        scale = np.where(log, 1.0, np.where(v > 0, np.abs(v), 1e-3 * hi))
        return cls(tuple(free), log, scale, lo, hi)

    def to_z(self, theta: np.ndarray) -> np.ndarray:
        theta = np.asarray(theta, float)
        return np.where(self.log, np.log(np.maximum(theta, 1e-300)), theta / self.scale)

    def to_theta(self, z: np.ndarray) -> np.ndarray:
        return np.where(self.log, np.exp(z), np.asarray(z) * self.scale)

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        return self.to_z(self.lo), self.to_z(self.hi)

    def dtheta_dz(self, theta: np.ndarray) -> np.ndarray:
        """``d theta / d z`` per parameter."""
        return np.where(self.log, theta, self.scale)


# ---- fractional delays ---------------------------------------------------------------------

def _cubic(y: np.ndarray, d: float, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """``y(t - d)`` and ``dy/dt (t - d)`` by cubic convolution (Keys, a = -1/2) on the
    sample grid ``k dt``; before the first sample the first value (the run starts settled),
    after the last the last."""
    n = y.size
    s = np.arange(n) - d / dt
    i = np.floor(s).astype(np.int64)
    f = s - i
    idx = np.clip(i[:, None] + np.arange(-1, 3)[None, :], 0, n - 1)
    p0, p1, p2, p3 = (y[idx[:, k]] for k in range(4))
    a = -0.5 * p0 + 1.5 * p1 - 1.5 * p2 + 0.5 * p3
    b = p0 - 2.5 * p1 + 2.0 * p2 - 0.5 * p3
    c = -0.5 * p0 + 0.5 * p2
    val = ((a * f + b) * f + c) * f + p1
    rate = ((3.0 * a * f + 2.0 * b) * f + c) / dt
    before, after = s <= 0, s >= n - 1
    val = np.where(before, y[0], np.where(after, y[-1], val))
    rate = np.where(before | after, 0.0, rate)
    return val, rate


def delayed(y: np.ndarray, d: float, dt: float, m: int = 1) -> np.ndarray:
    """``y(t - d)`` (see :func:`_cubic`) on the grid ``k dt``, then every ``m``-th sample
    (a model grid ``m`` times finer than the recording's)."""
    return (y if d == 0.0 else _cubic(y, d, dt)[0])[::m]


def _shifted(y: np.ndarray, m: int, step: int = 1) -> tuple[np.ndarray, ...]:
    """The cubic-convolution coefficients of ``y`` delayed by ``m - 1 + g`` samples, as
    ``(a, b, c, p)`` with the value ``((a (1-g) + b)(1-g) + c)(1-g) + p``: the four
    neighbours ``y[k-m-1 .. k-m+2]``, clamped at the ends (the run starts settled); at every
    ``step``-th ``k`` (a model grid finer than the recording's)."""
    n = y.size
    k = np.arange(0, n, step) - m
    p0, p1, p2, p3 = (y[np.clip(k + j, 0, n - 1)] for j in (-1, 0, 1, 2))
    return (-0.5 * p0 + 1.5 * p1 - 1.5 * p2 + 0.5 * p3, p0 - 2.5 * p1 + 2.0 * p2 - 0.5 * p3,
            -0.5 * p0 + 0.5 * p2, p1)


def _convolve(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The full linear convolution of ``a`` and ``b`` by FFT (``scipy.signal.fftconvolve``'s
    sum, without that module's half second of import on every calibration)."""
    from scipy import fft
    n = a.size + b.size - 1
    size = fft.next_fast_len(n, real=True)
    return fft.irfft(fft.rfft(a, size) * fft.rfft(b, size), size)[:n]


def _best_shift(parts, oks, lo_k: int, hi_k: int, offset: bool) -> int:
    """The whole-sample shift (of the model grid) in ``[lo_k, hi_k]`` with the least
    weighted sum of squares.

    Every sum over the samples is a correlation of the measured samples (placed on the
    model grid) with the model, clamped at its ends: all shifts at once by FFT
    (``sum r^2 = sum y^2 - 2 sum y m + sum m^2`` and ``sum r``, per shift). Only the best
    shift is kept, and :func:`best_delay` refines around it exactly."""
    ks = np.arange(lo_k, hi_k + 1)
    left = max(hi_k, 0)
    sse = np.zeros(ks.size)
    tot = np.zeros(ks.size)
    w_sum = 0.0
    for (y, meas, _, sg, step), ok in zip(parts, oks):
        idx = np.flatnonzero(ok)
        if not idx.size:
            continue
        # A constant off both changes no residual and keeps the sums small.
        c = float(np.mean(meas[idx]))
        m = meas[idx] - c
        # The model grid's sample j = step i holds the measured sample i; the model is
        # held at its ends beyond them.
        j = step * idx
        span = int(j[-1]) + 1
        right = max(-lo_k, 0) + max(span - y.size, 0)
        ext = np.concatenate([np.full(left, y[0]), y, np.full(right, y[-1])]) - c
        W = np.zeros(span)
        M = np.zeros(span)
        np.add.at(W, j, 1.0)
        np.add.at(M, j, m)

        def corr(a, b, span=span):
            # sum_j a[j] b[j - k + left] for every k in ks.
            return _convolve(b, a[::-1])[span - 1 + left - ks]
        yy = corr(W, ext * ext)
        ym = corr(M, ext)
        y1 = corr(W, ext)
        w = 1.0 / sg ** 2
        sse += w * (yy - 2.0 * ym + float(m @ m))
        tot += w * (y1 - float(m.sum()))
        w_sum += idx.size * w
    if offset and w_sum > 0:
        sse -= tot ** 2 / w_sum
    return int(ks[int(np.argmin(sse))])


def best_delay(parts, d_min: float, d_max: float, offset: bool) -> tuple[float, float]:
    """The delay in ``[d_min, d_max]`` (and the offset, with ``offset``) that minimise the
    weighted sum of squares of ``delayed(y, d, dt, step) + o - m`` over ``parts`` (``(y, m,
    dt, sigma, step)``: the model ``y`` on a grid ``dt``, ``step`` times finer than the
    measured ``m``; one ``dt`` for all), exactly: for a whole-sample shift the delayed model is a
    cubic in the fractional part (:func:`_cubic`), so the sum of squares is a polynomial of
    degree six in it, built from seven sums and minimised at its stationary points."""
    dt = parts[0][2]
    if any(abs(p[2] - dt) > 1e-9 * dt for p in parts):
        raise ValueError('a delay shared by recordings needs one sample period')
    oks = [np.isfinite(m) for _, m, _, _, _ in parts]
    w_sum = sum(int(ok.sum()) / sg ** 2 for ok, (_, _, _, sg, _) in zip(oks, parts))
    lo_k, hi_k = int(math.floor(d_min / dt)), int(math.ceil(d_max / dt))
    shifts = range(lo_k, max(hi_k, lo_k + 1))
    if len(shifts) > 6:
        # A wide window: the whole-sample shifts first (one matrix product), then the
        # polynomial around the best of them.
        k0 = _best_shift(parts, oks, lo_k, hi_k, offset)
        shifts = range(max(lo_k, k0 - 2), min(hi_k, k0 + 2) + 1)
    best = (math.inf, 0.0, 0.0)
    for m in shifts:
        # d = (m + f) dt; the sample k - m - f lies between k-m-1 and k-m at 1 - f.
        P = np.zeros(7)          # sum of squares in powers of f, f^0 .. f^6
        S = np.zeros(4)          # weighted sum of the residual (for the offset)
        for (y, meas, _, sg, step), ok in zip(parts, oks):
            a, b, c, p = (v[ok] for v in _shifted(y, m + 1, step))
            # In u = 1 - f: r = a u^3 + b u^2 + c u + (p - meas); rewrite in f.
            e0 = p - meas[ok]
            c3, c2, c1, c0 = -a, 3 * a + b, -(3 * a + 2 * b + c), a + b + c + e0
            w = 1.0 / sg ** 2
            cs = (c0, c1, c2, c3)
            for i in range(4):
                S[i] += w * float(cs[i].sum())
                for j in range(i, 4):
                    P[i + j] += (1.0 if i == j else 2.0) * w * float(cs[i] @ cs[j])
        if offset and w_sum > 0:
            # The best offset for each f removes (sum of w r)^2 / sum of w.
            P -= np.convolve(S, S) / w_sum
        f_lo = max(0.0, d_min / dt - m)
        f_hi = min(1.0, d_max / dt - m)
        if f_hi < f_lo:
            continue
        cand = [f_lo, f_hi]
        dP = np.polynomial.polynomial.polyder(P)
        if np.any(dP):
            for r in np.polynomial.polynomial.polyroots(np.trim_zeros(dP, 'b')):
                if abs(r.imag) < 1e-9 and f_lo < r.real < f_hi:
                    cand.append(float(r.real))
        vals = np.polynomial.polynomial.polyval(np.array(cand), P)
        i = int(np.argmin(vals))
        if vals[i] < best[0]:
            o = -float(np.polynomial.polynomial.polyval(cand[i], S)) / w_sum \
                if offset and w_sum > 0 else 0.0
            best = (float(vals[i]), (m + cand[i]) * dt, o)
    return best[1], best[2]


def timing_convention(delays: dict[str, dict[str, float]], dt: float) -> str:
    """In words, how the bench appears to stamp its signals, from the fitted delays
    (recording -> signal -> s; 'all' when shared) and the sample period ``dt``: a lead that
    every measured signal shares is the current stamped late (or the measurements early); a
    lag is a signal's own sensor chain (a flow meter, a filter), or, shared by all, the
    measurements stamped after a common delay."""
    per: dict[str, list[float]] = {}
    for v in delays.values():
        for sig, d in v.items():
            per.setdefault(sig, []).append(d)
    if not per or dt <= 0:
        return ''
    d = {sig: float(np.median(v)) for sig, v in sorted(per.items())}

    def listed(names):
        return ', '.join(f'{s} {1e3 * d[s]:+.3g} ms' for s in names)
    lead = [s for s, v in d.items() if v <= -0.5 * dt]
    lag = [s for s, v in d.items() if v >= 0.5 * dt]
    if lead:
        # No sensor answers before its cause: a lead is the stamps' doing.
        text = (f'the bench appears to stamp the current about {-1e3 * min(d.values()):.3g} ms '
                f'late against the measurements, or them early: {listed(lead)} lead it')
    elif len(lag) == len(d):
        return (f'every measured signal lags the current ({listed(lag)}): the bench appears '
                'to stamp the current at its command and the measurements after a common '
                'delay')
    else:
        text = 'the current and the measurements appear stamped on the same samples'
    if lag:
        text += f'; lagging by a sensor chain of their own: {listed(lag)}'
    return text


# ---- the problem ---------------------------------------------------------------------------

class Problem:
    """The weighted residuals of all experiments as a function of the plant coordinates ``z``
    (see the module)."""

    def __init__(self, engine: Engine, coords: Coordinates, *, offsets: Sequence[str] = (),
                 fit_delays: bool = True, per_bag: bool = False,
                 priors: Sequence[Prior] = (),
                 progress: Callable[[str], None] | None = None):
        self.engine, self.coords, self.exps = engine, coords, engine.exps
        self.blocks = [(i, s) for i, e in enumerate(self.exps) for s in e.measured]
        self.fit_delays = fit_delays
        self.per_bag = per_bag
        # The nuisance keys: (experiment or None, signal) -> the blocks they act on.
        self.keys: dict[tuple, list[tuple[int, str]]] = {}
        for b in self.blocks:
            self.keys.setdefault(self.key(*b), []).append(b)
        self.with_offset = {k for k in self.keys if k[1] in offsets}
        self.nuis = {k: (0.0, 0.0) for k in self.keys}   # (delay s, offset): warm starts
        self.n_plant = len(coords.names)
        # The delays' window: a few recorded samples of lead up to DELAY_MAX of lag.
        self.delay_min = -LEAD_SAMPLES * max((e.dt for e in self.exps), default=0.0)
        self.priors = list(priors)
        index = {n: j for j, n in enumerate(coords.names)}
        self._prior_cols = [index[p.name] for p in self.priors]
        self._prior_z = np.array([self._z_of(j, p.value) for j, p in
                                  zip(self._prior_cols, self.priors)])
        self._prior_sd = np.array([self._prior_sd_of(j, p) for j, p in
                                   zip(self._prior_cols, self.priors)])
        self._evals: dict[bytes, tuple] = {}
        self._sens: dict[bytes, tuple] = {}
        self._progress = progress

    # ---- priors ------------------------------------------------------------------------

    def _z_of(self, j: int, value: float) -> float:
        """The search coordinate of parameter ``j`` at ``value``."""
        return math.log(value) if self.coords.log[j] else value / float(self.coords.scale[j])

    def _prior_sd_of(self, j: int, p: Prior) -> float:
        """The prior's standard deviation in the search coordinate of parameter ``j``."""
        if self.coords.log[j]:
            return math.log1p(p.rel)
        return p.rel * p.value / float(self.coords.scale[j])

    def prior_rows(self, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The prior residuals and their Jacobian rows (on the plant columns)."""
        k = len(self.priors)
        r = (np.asarray(z)[self._prior_cols] - self._prior_z) / self._prior_sd if k else \
            np.zeros(0)
        J = np.zeros((k, self.n_plant))
        for row, (j, sd) in enumerate(zip(self._prior_cols, self._prior_sd)):
            J[row, j] = 1.0 / sd
        return r, J

    # ---- coordinates -------------------------------------------------------------------

    def theta(self, z: np.ndarray) -> np.ndarray:
        return self.coords.to_theta(z)

    def key(self, i: int, s: str) -> tuple:
        return (i if self.per_bag else None, s)

    # ---- the nuisance parameters -------------------------------------------------------

    def _inner(self, parts, start: float, offset: bool, search: bool) -> tuple[float, float]:
        """The delay (and offset) that fit the simulated ``y`` to the measured ``m`` of
        every ``(y, m, dt, sigma)`` in ``parts`` best: over every whole-sample shift in
        ``[delay_min, DELAY_MAX]`` with ``search``, else within two samples of ``start``
        (see :func:`best_delay`)."""
        if not self.fit_delays:
            return 0.0, best_delay(parts, 0.0, 0.0, offset)[1]
        if search:
            return best_delay(parts, self.delay_min, DELAY_MAX, offset)
        dt = parts[0][2]
        return best_delay(parts, max(self.delay_min, start - 2 * dt),
                          min(DELAY_MAX, start + 2 * dt), offset)

    def evaluate(self, z: np.ndarray, search: bool = False):
        """``(sims, nuisance, residuals)`` at ``z`` (cached)."""
        key = np.asarray(z, float).tobytes()
        if key in self._evals and not search:
            return self._evals[key]
        sims = self.engine.outputs(self.theta(z))
        return self._settle(key, sims, search)

    def _settle(self, key: bytes, sims, search: bool):
        nuis = {}
        for k, blocks in self.keys.items():
            parts = [(sims[i][s], self.exps[i].measured[s], self.exps[i].dt_model,
                      self.exps[i].sigma[s], self.exps[i].fine) for i, s in blocks]
            nuis[k] = self._inner(parts, self.nuis[k][0], k in self.with_offset, search)
        self.nuis = nuis
        r = np.concatenate(list(self._residual_blocks(self._apply(sims, nuis))))
        if len(self._evals) > 16:
            self._evals.clear()
        self._evals[key] = (sims, nuis, r)
        return sims, nuis, r

    def _apply(self, sims, nuis) -> list[dict[str, np.ndarray]]:
        out = []
        for i, (e, sim) in enumerate(zip(self.exps, sims)):
            out.append({s: delayed(sim[s], nuis[self.key(i, s)][0], e.dt_model, e.fine)
                        + nuis[self.key(i, s)][1] for s in e.measured})
        return out

    def residuals_of(self, sims, nuis) -> np.ndarray:
        """The data residuals of simulated signals ``sims`` (per experiment, as
        :meth:`.engine.Engine.outputs` gives them) with the delays and offsets ``nuis``."""
        return np.concatenate(list(self._residual_blocks(self._apply(sims, nuis))))

    def predictions(self, z: np.ndarray) -> list[dict[str, np.ndarray]]:
        """The model's measurements (delays and offsets applied) per experiment."""
        sims, nuis, _ = self.evaluate(z)
        return self._apply(sims, nuis)

    def _residual_blocks(self, pred):
        for e, p in zip(self.exps, pred):
            for s, y in e.measured.items():
                r = (p[s] - y) / e.sigma[s]
                yield np.where(np.isfinite(r), r, 0.0)

    def data_residuals(self, z: np.ndarray) -> np.ndarray:
        return self.evaluate(z)[2]

    def residuals(self, z: np.ndarray) -> np.ndarray:
        """Data residuals, then one row per prior."""
        try:
            r = self.evaluate(z)[2]
        except HydropumpError:
            # A trial point where the model cannot be integrated or trimmed: a large residual
            # sends the trust region back.
            r = np.full(self.n_rows, 1e6)
        return np.concatenate([r, self.prior_rows(z)[0]])

    @property
    def n_rows(self) -> int:
        return sum(e.n * len(e.measured) for e in self.exps)

    def row_groups(self) -> list[slice]:
        """Row ranges of each (experiment, signal) block: independent noise records."""
        out, k = [], 0
        for e in self.exps:
            for _ in e.measured:
                out.append(slice(k, k + e.n))
                k += e.n
        return out

    def block_rms(self, r: np.ndarray) -> list[float]:
        """RMS of the weighted residuals per block (1 at the noise level)."""
        return [float(np.sqrt(np.mean(r[g] ** 2))) for g in self.row_groups()]

    def at_noise_level(self, r: np.ndarray, factor: float = 2.0) -> bool:
        """Do the residuals of most signals reach their noise level (an rms of the weighted
        residuals within ``factor``)? A fit stuck in a local minimum leaves whole signals
        far above it."""
        return bool(np.median(self.block_rms(r[:self.n_rows])) <= factor)

    # ---- sensitivities -----------------------------------------------------------------

    def sensitivities(self, z: np.ndarray, nuis=None) -> tuple[np.ndarray, np.ndarray]:
        """``(J_plant, J_nuisance)`` of the data rows: the plant columns from copies stepped
        with the nominal run (:meth:`.engine.Engine.sensitivity_runs`, the nuisance
        parameters held), and the exact columns of the free nuisance parameters (a delay:
        ``-y'(t - d)``; an offset: one). A delay on a bound is not free."""
        key = np.asarray(z, float).tobytes()
        if nuis is None and key in self._sens:
            return self._sens[key]
        n = self.n_plant
        lo, hi = self.coords.bounds()
        steps = np.empty(n)
        thetas = []
        for j in range(n):
            h = self.engine.sensitivity_step * (1.0 if self.coords.log[j] else max(abs(z[j]), 1.0))
            if z[j] + h > hi[j]:
                h = -h
            zj = np.array(z, float)
            zj[j] += h
            steps[j] = h
            thetas.append(self.coords.to_theta(zj))
        nominal, perturbed = self.engine.sensitivity_runs(self.theta(z), thetas)
        held = nuis is not None
        if nuis is None:
            nuis = self._evals[key][1] if key in self._evals else \
                self._settle(key, nominal, False)[1]
        r0 = np.concatenate(list(self._residual_blocks(self._apply(nominal, nuis))))
        Jp = np.zeros((r0.size, n))
        for j in range(n):
            rj = np.concatenate(list(self._residual_blocks(self._apply(perturbed[j], nuis))))
            Jp[:, j] = (rj - r0) / steps[j]
        rows = dict(zip(self.blocks, self.row_groups()))
        cols = []
        for nkey, blocks in self.keys.items():
            d, _ = nuis[nkey]
            cd, co = np.zeros(r0.size), np.zeros(r0.size)
            for i, s in blocks:
                e = self.exps[i]
                ok = np.isfinite(e.measured[s])
                g = rows[(i, s)]
                cd[g] = -_cubic(nominal[i][s], d, e.dt_model)[1][::e.fine] / e.sigma[s] * ok
                co[g] = ok / e.sigma[s]
            if self.fit_delays and self.delay_min < d < DELAY_MAX:
                cols.append(cd)
            if nkey in self.with_offset:
                cols.append(co)
        Jn = np.column_stack(cols) if cols else np.zeros((r0.size, 0))
        if self._progress:
            self._progress(f'{self.engine.n_trajectories} simulated runs')
        if not held:
            # The last two points: a Jacobian asked for again (the trust region's first and
            # last, the analysis at the solution) costs no simulation.
            if len(self._sens) > 1:
                self._sens.pop(next(iter(self._sens)))
            self._sens[key] = (Jp, Jn)
        return Jp, Jn

    def jacobian(self, z: np.ndarray) -> np.ndarray:
        """The plant Jacobian with the nuisance directions projected out, then the prior
        rows."""
        Jp, Jn = self.sensitivities(z)
        if Jn.shape[1]:
            Q, _ = np.linalg.qr(Jn)
            Jp = Jp - Q @ (Q.T @ Jp)
        return np.vstack([Jp, self.prior_rows(z)[1]])
