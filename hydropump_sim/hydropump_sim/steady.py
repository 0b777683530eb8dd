"""The one steady-state search, for any :class:`~hydropump_sim.system.Model`.

A steady state holds every state still except the *integrating* ones (a cylinder's
position, which moves at a constant velocity wherever the piston is): they keep their start
values, unless one sits on an end stop and is pushed into it (then it rests too). The
search polishes the model's own starts (:meth:`Model.start_states`: the paper pump's
closed form, a circuit's pressures from its loads) by Newton's method; where none is a
steady state the model can hold, it marches the dynamics with the inputs held until the
free states settle, then polishes. There is no other path: the pump alone and
every circuit take this one.

Every valve leaks (components/laws.py), so no volume is sealed and every node's pressure is
determined: a dead-ended volume rests at what its leakages settle it at.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
import time

import numpy as np
from scipy import linalg, optimize

from . import integrator as ig
from .errors import HydropumpError
from .system import Model, SteadyState

#: Modes slower than this [s] keep their start in a steady state where the state cannot
#: otherwise come to rest: a volume that only leakage reaches (a cylinder's chamber behind a
#: closed spool and a holding valve settles over seconds to minutes: an excavator's boom,
#: 6 to 100 s) rests at what feeds it, or where a run left it, and drifts from there as
#: the hardware does.
SLOW = 5.0


class TrimError(HydropumpError, ValueError):
    """No steady state exists, or none was found, at the requested inputs."""


def equilibrium(model: Model, u=None, *, x0=None, tol: float = 1.0e-9,
                horizon: float = 30.0, time_budget: float = 30.0, strict: bool = True,
                accept: float = 1.0e-5) -> SteadyState:
    """The steady state of ``model`` at held inputs ``u`` (a vector, or values by name;
    default the model's).

    Parameters
    ----------
    x0 : array_like, optional
        Where to start (a nearby steady state); default the model's own starts.
    tol : float
        The scaled residual aimed at: each free state's rate over a 1 ms horizon, as a
        fraction of its scale.
    horizon, time_budget : float
        How long the march may run, in simulated and wall seconds.
    strict : bool
        Raise :class:`TrimError` when no steady state is found (else return the nearest
        state, its ``residual`` saying how far from rest).
    accept : float
        The scaled residual still accepted as rest (a nearly singular state: one per cent
        of a state's scale per second at 1e-5).
    """
    if u is None or isinstance(u, Mapping):
        u = model.input_vector(u)
    u = np.asarray(u, dtype=float)
    search = _Search(model, u, tol, accept)
    starts = [np.array(x0, dtype=float)] if x0 is not None else model.start_states(u)
    x, stopped = search.from_starts(starts, horizon, time_budget)
    x = search.onto_stops(x)
    if strict and not search.good(x, accept):
        why = model.unphysical(x, u) or (
            f'the state does not settle (scaled residual {search.worst(x):.2e} above '
            f'{accept:.0e}): ' + _describe(model, x, u, search.p))
        raise TrimError(f'{model.name}: no steady state found at '
                        f'{_inputs_text(model, u)}: {why}'
                        + (f'; {stopped}' if stopped else ''))
    return SteadyState(model, x, u, model.rhs(0.0, x, u)[1], search.settled(x))


class _Search:
    """One search of :func:`equilibrium`: the model at held inputs, the states that rest
    (``free``: all but the integrating ones, and those pinned on a stop), and the basis of
    the fast modes while a quasi-steady state is judged."""

    def __init__(self, model: Model, u: np.ndarray, tol: float, accept: float):
        self.model, self.u, self.tol, self.accept = model, u, tol, accept
        self.p = model.p_steady
        self.scale = model.state_scale
        self.free = ~model.integrating
        self.basis = None
        self._dx = np.empty(model.n_states)
        self._y = np.empty(model.n_signals)

    def rates(self, xv):
        self.model.evaluate(0.0, xv, self.u, self.p, self._dx, self._y)
        return self._dx

    def worst(self, xv) -> float:
        """The largest scaled rate of a free state over a 1 ms horizon."""
        free, scale = self.free, self.scale
        return float(np.max(np.abs(self.rates(xv)[free] * 1.0e-3 / scale[free]), initial=0.0))

    def polish(self, xv):
        # Newton's method (Powell's hybrid), again from where it stopped while it gains
        # (nearly sealed volumes make the Jacobian ill-conditioned: their leakages are
        # 1e-6 of an open passage's), then Levenberg-Marquardt.
        free, scale = self.free, self.scale
        for method in ('hybr', 'hybr', 'hybr', 'lm'):
            if self.worst(xv) <= self.tol:
                break

            def resid(z, xv=xv):
                xt = xv.copy()
                xt[free] = z * scale[free]
                return self.rates(xt)[free] * 1.0e-3 / scale[free]
            sol = optimize.root(resid, xv[free] / scale[free], method=method,
                                options={'xtol': 1e-13})
            out = xv.copy()
            out[free] = sol.x * scale[free]
            if not (np.all(np.isfinite(out)) and self.worst(out) < self.worst(xv)):
                continue
            xv = out
        return xv

    def quasi(self, xv):
        """The quasi-steady state from ``xv``: modes slower than :data:`SLOW` (a volume
        that only leakage reaches) keep their start, the others rest (their rates, in the
        real Schur basis that orders the modes, are zero). ``None`` without slow modes."""
        free = self.free
        sf = self.scale[free]
        A = self.model.jacobian(0.0, xv, self.u, self.p)[np.ix_(free, free)] \
            * sf[None, :] / sf[:, None]
        if not np.all(np.isfinite(A)):
            return None
        T, Qs, k = linalg.schur(A, output='real',
                                sort=lambda re, im: abs(complex(re, im)) < 1.0 / SLOW)
        if k == 0 or k == A.shape[0]:
            return None
        Qf, Qslow = Qs[:, k:], Qs[:, :k]
        z0 = xv[free] / sf

        def F(z):
            xt = xv.copy()
            xt[free] = z * sf
            return np.concatenate([Qf.T @ (self.rates(xt)[free] / sf), Qslow.T @ (z - z0)])
        sol = optimize.root(F, z0, method='hybr', options={'xtol': 1e-13})
        out = xv.copy()
        out[free] = sol.x * sf
        self.basis = Qf
        return out if np.all(np.isfinite(out)) else None

    def settled(self, xv) -> float:
        """The scaled residual of the modes that rest (all, or the fast ones)."""
        if self.basis is None:
            return self.worst(xv)
        Qf, free = self.basis, self.free
        r = Qf @ (Qf.T @ (self.rates(xv)[free] / self.scale[free]))
        return float(np.max(np.abs(r)) * 1.0e-3)

    def good(self, xv, level: float) -> bool:
        return self.model.unphysical(xv, self.u) is None and self.settled(xv) <= level

    def _polished(self, xv):
        """``xv`` polished if the model can hold it (else as it is)."""
        return self.polish(xv) if self.model.unphysical(xv, self.u) is None else xv

    def from_starts(self, starts: list, horizon: float, time_budget: float
                    ) -> tuple[np.ndarray, str]:
        """The first start that polishes to rest; else the first's quasi-steady state; else
        a march of the dynamics from it, polished. Returns the state and why a march
        stopped early (``''``)."""
        tight = max(self.tol, 1.0e-7)
        for cand in starts:
            xp = self._polished(cand)
            if self.good(xp, tight):
                return xp, ''
        if self.model.unphysical(starts[0], self.u) is None:
            xq = self.quasi(self.polish(starts[0]))
            if xq is not None and self.good(xq, self.accept):
                return xq, ''
        self.basis = None
        model = self.model
        start = model.clip_start(starts[0]) if hasattr(model, 'clip_start') else starts[0]
        found = {}

        def done(xm, k):
            # Settled, or (every second of the march) at rest but for its slow modes.
            if self.worst(xm) < 1.0e-9:
                return True
            if k % 5 == 4:
                xq = self.quasi(self.polish(xm))
                if xq is not None and self.good(xq, self.accept):
                    found['x'] = xq
                    return True
                self.basis = None
            return False
        marched, stopped = _march(model, start, self.u, self.p, horizon, time_budget, done)
        if 'x' in found:
            return found['x'], stopped
        xp = self.polish(marched)
        return (xp if self.good(xp, tight) or self.worst(xp) < self.worst(marched)
                else marched), stopped

    def onto_stops(self, x):
        """``x`` with every integrating state pressed on an end stop at rest too: its
        position joins the states that rest, where the stop's force balances the push."""
        model, scale = self.model, self.scale
        pinned = _on_stops(model, x, self.rates(x)) & ~self.free
        if not pinned.any():
            return x
        self.free = self.free | pinned
        self.basis = None
        # Start just inside the stop, where its stiffness is felt (Newton stalls on the
        # contact's edge, where the stop's force does not yet depend on the position).
        x = x.copy()
        hi = pinned & (x >= model.state_stops[:, 1])
        x[hi] = np.maximum(x[hi], model.state_stops[hi, 1] + 1.0e-6 * scale[hi])
        lo = pinned & ~hi
        x[lo] = np.minimum(x[lo], model.state_stops[lo, 0] - 1.0e-6 * scale[lo])
        # ... and stop what drives it (its velocity: one Newton step on its own rate).
        J = model.jacobian(0.0, x, self.u, self.p)
        r = self.rates(x).copy()
        for k in np.flatnonzero(pinned):
            row = np.abs(J[k]) * scale
            row[k] = 0.0
            j = int(np.argmax(row))
            if J[k, j] != 0.0:
                x[j] -= r[k] / J[k, j]
        xp = self.polish(x)
        if not self.good(xp, max(self.tol, 1.0e-7)):
            xq = self.quasi(xp)
            xp = xq if xq is not None and self.good(xq, self.accept) else xp
        return xp


def _on_stops(model: Model, x: np.ndarray, dx: np.ndarray) -> np.ndarray:
    """The integrating states at one of their stops and pushed beyond it."""
    stops = model.state_stops
    if stops is None:
        return np.zeros(model.n_states, dtype=bool)
    with np.errstate(invalid='ignore'):
        return model.integrating & (((x >= stops[:, 1]) & (dx > 0.0))
                                    | ((x <= stops[:, 0]) & (dx < 0.0)))


def _inputs_text(model: Model, u: np.ndarray) -> str:
    describe = getattr(model, 'describe_inputs', None)
    return describe(u) if describe else 'the held inputs'


def _march(model: Model, x: np.ndarray, u: np.ndarray, p: np.ndarray, horizon: float,
           time_budget: float, done: Callable[[np.ndarray, int], bool]
           ) -> tuple[np.ndarray, str]:
    """Integrate with held inputs, in chunks of 0.2 s, until ``done(x, chunk)`` (the
    integrating states held at their start). Returns the state and why the march stopped
    early (``''`` if it did not)."""
    dt, chunk = 1.0e-3, 200
    U = np.tile(u, (chunk, 1))
    # Only each chunk's end is wanted, and the inputs hold: steps free of the increments.
    Y = np.empty((1, 2, model.n_signals))
    X = np.empty((1, 2, model.n_states))
    stats = np.zeros(2, dtype=np.int64)
    stepper = model.stepper_model(timed=False)
    held = x[model.integrating].copy()
    t0 = time.perf_counter()
    for k in range(int(horizon / (dt * chunk))):
        status, _ = ig.run_dense(stepper, x[None].copy(), k * dt * chunk, dt, U, p[None],
                                 1.0e-6, 1.0e-12, 20000, chunk, Y, X, stats, 2_000_000, False)
        if status == ig.FAIL_BUDGET:
            return x, ('the integration toward it took more than 2e+06 solver steps (the '
                       'parameters make the model very stiff)')
        if status != ig.OK:
            return x, 'the integration toward it failed'
        x = X[0, -1].copy()
        x[model.integrating] = held
        if done(x, k):
            break
        if time.perf_counter() - t0 > time_budget:
            return x, f'the integration toward it ran out of its {time_budget:g} s time budget'
    return x, ''


def _describe(model: Model, x: np.ndarray, u: np.ndarray, p: np.ndarray) -> str:
    """The states that still move most, for the error."""
    dx, _ = model.rhs(0.0, x, u, p)
    r = np.abs(dx) * 1.0e-3 / model.state_scale
    r[model.integrating] = 0.0
    worst = np.argsort(-r)[:3]
    return ', '.join(f'{model.states[k]} moves at {dx[k]:.3g} {model.state_units[k]}/s'
                     for k in worst if r[k] > 0)


def trim_input(model: Model, name: str, target: Callable[[SteadyState], float], u=None, *,
               bounds: tuple[float, float] | None = None,
               xtol: float = 1.0e-7) -> tuple[SteadyState, bool]:
    """The steady state where ``target(eq) = 0`` by the held input ``name`` (the pump's
    current for a margin): returns it and whether the target was reached (``False``: the
    input is at the end of its range, e.g. a demand beyond the pump's maximum flow)."""
    if u is None or isinstance(u, Mapping):
        u = model.input_vector(u)
    u = np.array(u, dtype=float)
    k = model.input_index(name)
    lo, hi = bounds or model.input_ranges[k]
    cache: dict[float, SteadyState] = {}
    last = [None]

    def at(v):
        if v not in cache:
            uu = u.copy()
            uu[k] = v
            cache[v] = equilibrium(model, uu, x0=last[0])
            last[0] = cache[v].x
        return cache[v]

    f_lo, f_hi = target(at(lo)), target(at(hi))
    if f_lo * f_hi > 0.0:
        end = lo if abs(f_lo) < abs(f_hi) else hi
        return at(end), False
    v = optimize.brentq(lambda v: target(at(v)), lo, hi, xtol=xtol)
    return at(v), True


#: The package's name for the one search (``hydropump_sim.steady_state``).
steady_state = equilibrium
