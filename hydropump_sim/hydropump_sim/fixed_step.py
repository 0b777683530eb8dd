"""A step for real time, of bounded work, checked on the model before it runs.

``Simulator(fixed_step=h, max_steps=M)`` integrates each increment in Rodas4 steps of at
most ``h``, shorter where the error control asks (a valve slammed, a spool at its stop),
but tries at most ``M`` of them: the last ones are taken whatever their error. An
increment's work is then at most ``M`` Jacobians, factorisations and six stages, a bound a
real-time loop can plan on, and the error is controlled wherever that bound allows. Where
it does not (a switch that would need more), nothing controls it: a step or a bound too
small for the fastest dynamics the model keeps (a circuit's small volumes behind its
orifices and seats) leaves the true solution, or diverges. Rodas4 is L-stable, so no
eigenvalue says which; what decides is non-smooth, and found by running it. :func:`check`
runs a switching test run (:func:`switching_inputs`: every input thrown to the far end of
its range and back) with the step and bound and with error control alone, and takes the
step where the two agree within :data:`TOLERANCE` of every judged signal's excursion;
otherwise it names the largest step that does at the same bound.
"""

from __future__ import annotations

from dataclasses import dataclass
import math
import time

import numpy as np

from .errors import InputError
from .reduction import staggered
from .simulate import bounded_steps, IntegrationError, simulate, Simulator, steps_of
from .steady import equilibrium
from .system import Model

#: The largest deviation from the error-controlled run a fixed step may make on the test
#: run, as a fraction of each judged signal's excursion there.
TOLERANCE = 0.01
#: The test run [s].
DURATION = 0.5


@dataclass(frozen=True)
class FixedStep:
    """A checked step: ``step`` [s], at most ``max_steps`` Rodas4 steps an increment and
    ``evaluations`` of the model (the work's bound: per step one per Jacobian colour, six
    stages and one at its start), and on the test run its ``error`` (fraction of
    excursion, the worst signal ``worst``) and the wall time of an increment (``cost_p99``
    and ``cost_max`` [s])."""

    step: float
    max_steps: int
    evaluations: int
    error: float
    worst: str
    cost_p99: float
    cost_max: float

    def text(self) -> str:
        return (f'fixed step {self.step:.3g} s, at most {self.max_steps} Rodas4 steps an '
                f'increment ({self.evaluations} model evaluations); on the test run within '
                f'{self.error:.2%} of the error-controlled run, p99 '
                f'{self.cost_p99 * 1e6:.0f} us an increment')


def switching_inputs(model: Model, duration: float) -> dict:
    """Every main input (the pump's current too) thrown from where it holds to the far end
    of its range at staggered instants in the first half of ``duration``, and back at the
    same instants of the second half: valves slammed open and shut, the spool at its stop,
    what a real-time step must survive."""
    return staggered(model, duration, lambda name, u0, lo, hi:
                     hi if hi - u0 >= u0 - lo else lo, back=True)


def _trial(model: Model, dt: float, step: float, max_steps: int, U: np.ndarray,
           x0: np.ndarray, ref, names: list[str]) -> tuple[float, str, np.ndarray]:
    """The deviation of a run at ``step`` from ``ref`` (inf if it fails), the worst signal,
    and each increment's wall time."""
    sim = Simulator(model, dt, x0=x0, fixed_step=step, max_steps=max_steps)
    sim.x = np.array(x0, dtype=float)
    sim.t, sim.steps = 0.0, 0
    idx = [model.signal_index(n) for n in names]
    Y = np.empty((len(U), len(idx)))
    costs = np.empty(len(U))
    try:
        for k, u in enumerate(U):
            sim.u[:] = u
            t0 = time.perf_counter()
            sim.step()
            costs[k] = time.perf_counter() - t0
            Y[k] = sim.outputs()[idx]
    except IntegrationError:
        return math.inf, 'the run fails', costs
    worst = (0.0, names[0])
    for j, n in enumerate(names):
        a = ref[n][1:len(U) + 1]
        span = max(float(np.ptp(a)), 1e-3 * float(np.max(np.abs(a))), 1e-12)
        e = float(np.max(np.abs(Y[:, j] - a))) / span
        worst = max(worst, (e if math.isfinite(e) else math.inf, n))
    return worst[0], worst[1], costs


def _test_run(model: Model, dt: float) -> tuple:
    """The switching test run, held per increment ``dt``, and its error-controlled run:
    ``(x0, U, ref, names)``."""
    eq = equilibrium(model)
    ins = switching_inputs(model, DURATION)
    U, _ = model.input_table(np.arange(int(round(DURATION / dt))) * dt, ins, dt)
    ref = simulate(model, DURATION, ins, x0=eq.x, dt_out=dt, dt_max=dt)
    return eq.x, U, ref, model.judged_signals()


def _checked(model: Model, dt: float, step: float, max_steps: int, run: tuple) -> FixedStep:
    """``step`` at ``max_steps`` on the test run ``run`` (:func:`_test_run`), whatever its
    error."""
    x0, U, ref, names = run
    e, worst, costs = _trial(model, dt, step, max_steps, U, x0, ref, names)
    colors = int(np.max(model.structure()['colors'])) + 1
    return FixedStep(step, max_steps, max_steps * (colors + 7), e, worst,
                     float(np.percentile(costs, 99)), float(np.max(costs)))


def _largest(model: Model, dt: float, max_steps: int, run: tuple, first: int
             ) -> FixedStep | None:
    """The largest step ``dt/n`` (``n`` from ``first`` up to ``max_steps``) that holds."""
    for n in range(first, max_steps + 1):
        held = _checked(model, dt, dt / n, max_steps, run)
        if held.error <= TOLERANCE:
            return held
    return None


def largest_step(model: Model, dt: float, max_steps: int = 16) -> FixedStep | None:
    """The largest step of the form ``dt/n`` that holds on ``model`` at ``max_steps``
    (checked as :func:`check` checks one), or ``None``."""
    return _largest(model, dt, max_steps, _test_run(model, dt), 1)


def check(model: Model, dt: float, step: float, max_steps: int = 16) -> FixedStep:
    """``step`` [s] with at most ``max_steps`` an increment checked on ``model`` stepped
    every ``dt`` (see the module), or an :class:`InputError` naming the largest step of the
    form ``dt/n`` that holds at that bound (``n`` up to ``max_steps``)."""
    bounded_steps(dt, step, max_steps)
    run = _test_run(model, dt)
    checked = _checked(model, dt, step, max_steps, run)
    e = checked.error
    if e > TOLERANCE:
        held = _largest(model, dt, max_steps, run, steps_of(dt, step) + 1)
        what = 'diverges' if not e < 10.0 else f'leaves it by {e:.1%} ({checked.worst})'
        raise InputError(
            f'solver.fixed_step = {step:g} s (max_steps {max_steps}): too large for the '
            f'fastest dynamics {model.name} keeps: on its test run it {what} against the '
            'error-controlled run; '
            + (f'the largest step that holds within {TOLERANCE:.0%} is {held.step:.4g} s '
               f'(dt/{round(dt / held.step)})' if held is not None else
               f'no step down to dt/{max_steps} holds within {TOLERANCE:.0%}: raise '
               'solver.max_steps, or use adaptive steps (fixed_step 0)'))
    return checked
