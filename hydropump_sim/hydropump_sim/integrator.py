"""The Rodas4 stepper, compiled once for every model: the pump alone and any circuit.

A model is a compiled function ``evaluate(t, x, u, p, dx, y)`` of signature
:data:`EVALUATE` (a numba ``cfunc``) that fills the state derivative ``dx`` and the outputs
``y`` from the time ``t``, the state ``x``, the held inputs ``u`` and the packed parameters
``p`` (all float64 arrays). The stepper calls it through its address, as a first-class
function, so it is compiled, and cached, once: a new model or circuit costs its own
equations only. (The address, an integer, and not the cfunc object: numba types a cfunc
argument in Python on every call, about 200 us, twenty times a plant's 1 ms step.)

What the stepper needs to know of a model besides its function is its *structure*:

- ``scale``: the typical magnitude of each state (absolute tolerances, difference steps);
- ``colors`` and ``pattern``: a partition of the states whose columns of ``df/dx`` share no
  row (``pattern[i, j]``: ``f_i`` may depend on ``x_j``), so that one evaluation per colour
  gives the whole finite-difference Jacobian (Curtis, Powell and Reid). The pump alone is
  dense (a colour per state); a circuit's components touch only their own ports;
- ``timed``: whether ``f`` depends on time within a held increment (a dither), which
  Rosenbrock methods take into account through ``df/dt``.
"""

import math
import warnings

from numba import types
from numba.core import cgutils
from numba.core.errors import NumbaExperimentalFeatureWarning
from numba.extending import intrinsic
import numpy as np

from .jitcache import inline, jit

# Models are first-class functions to the stepper (numba calls the feature experimental; it
# is what lets the stepper compile once for every model).
warnings.filterwarnings('ignore', category=NumbaExperimentalFeatureWarning)

#: Signature of a model's ``evaluate(t, x, u, p, dx, y)``.
_A = types.float64[::1]
EVALUATE = types.void(types.float64, _A, _A, _A, _A, _A)
_FUNCTION = types.FunctionType(EVALUATE)


@intrinsic
def as_function(typingctx, f):
    """A model's ``evaluate`` from its cfunc's address (or the function itself)."""
    if isinstance(f, types.FunctionType):
        return f(f), lambda context, builder, sig, args: args[0]
    if not isinstance(f, types.Integer):
        return None

    def codegen(context, builder, sig, args):
        fn = cgutils.create_struct_proxy(_FUNCTION)(context, builder)
        ptr = context.get_value_type(types.voidptr)
        fn.c_addr = builder.inttoptr(args[0], ptr)
        fn.py_addr = ptr(None)
        fn.jit_addr = ptr(None)
        return fn._getvalue()
    return _FUNCTION(f), codegen

# Rodas4 (Hairer & Wanner, Solving ODEs II, sec. IV.7), in the form
#   (I/(h g) - J) k_i = f(t + a_i h, x + sum_j A_ij k_j) + sum_j C_ij k_j / h + h g_i f_t.
_GAM = 0.25
_ALPHA = np.array([0.0, 0.386, 0.21, 0.63, 1.0, 1.0])
_GAMMA = np.array([0.25, -0.1043, 0.1035, -0.0362, 0.0, 0.0])
_A6 = np.zeros((6, 6))
_C6 = np.zeros((6, 6))
_A6[1, 0] = 1.544
_A6[2, :2] = (0.9466785280815826, 0.2557011698983284)
_A6[3, :3] = (3.314825187068521, 2.896124015972201, 0.9986419139977817)
_A6[4, :4] = (1.221224509226641, 6.019134481288629, 12.53708332932087, -0.687886036105895)
_A6[5, :5] = (1.221224509226641, 6.019134481288629, 12.53708332932087, -0.687886036105895, 1.0)
_C6[1, 0] = -5.6688
_C6[2, :2] = (-2.430093356833875, -0.2063599157091915)
_C6[3, :3] = (-0.1073529058151375, -9.594562251023355, -20.47028614809616)
_C6[4, :4] = (7.496443313967647, -10.24680431464352, -33.99990352819905, 11.7089089320616)
_C6[5, :5] = (8.083246795921522, -7.981132988064893, -31.52159432874371, 16.31930543123136,
              -6.058818238834054)
# Stiffly accurate: the solution is the 6th stage, the error estimate is k_6.
_M = np.array([1.221224509226641, 6.019134481288629, 12.53708332932087, -0.687886036105895,
               1.0, 1.0])
# Dense output of the same method (Hairer's RODAS): within a step of size h from x0 to x1,
#   x(t + s h) = x0 + s (x1 - x0 + (1 - s) (c2 + s c3)),  c2 = sum D2_i k_i, c3 = sum D3_i k_i.
_D2 = np.array([10.12623508344586, -7.487995877610167, -34.80091861555747, -7.992771707568823,
                1.025137723295662])
_D3 = np.array([-0.6762803392801253, 6.087714651680015, 16.43084320892478, 24.76722511418386,
                -6.594389125716872])

# Integration status codes.
OK, FAIL_STEP, FAIL_NAN, FAIL_STEPS, FAIL_BUDGET = 0, 1, 2, 3, 4



@jit
def call(f, t, x, u, p, dx, y):
    """Evaluate a model's compiled ``f`` (its address) once (from Python: analysis, steady
    states)."""
    as_function(f)(t, x, u, p, dx, y)


def model(f, st: dict) -> tuple:
    """What the stepper takes of a model: its ``evaluate`` (a cfunc of :data:`EVALUATE`)
    and its structure ``st`` (``scale``, ``timed``, ``dt_time``, ``colors``, ``pattern``;
    see the module), as one tuple (the function as its address)."""
    return (f.address, np.ascontiguousarray(st['scale'], dtype=np.float64), bool(st['timed']),
            float(st['dt_time']), st['colors'], st['pattern'])


def dense(n: int) -> tuple[np.ndarray, np.ndarray]:
    """``colors`` and ``pattern`` of a model whose every derivative may depend on every
    state (a colour per state)."""
    return np.arange(n, dtype=np.int64), np.ones((n, n), dtype=np.bool_)


def coloring(pattern: np.ndarray) -> np.ndarray:
    """A greedy partition of the columns of ``pattern`` (n x n, bool) into groups whose
    columns share no row: the colours of :func:`jacobian`."""
    n = pattern.shape[1]
    colors = -np.ones(n, dtype=np.int64)
    used: list[np.ndarray] = []          # rows taken by each colour
    order = np.argsort(-pattern.sum(axis=0), kind='stable')
    for j in order:
        rows = pattern[:, j]
        for c, taken in enumerate(used):
            if not np.any(taken & rows):
                colors[j] = c
                used[c] = taken | rows
                break
        else:
            colors[j] = len(used)
            used.append(rows.copy())
    return colors


@jit
def jacobian(f, t, x, u, p, f0, scale, J, work, ybuf, colors, pattern):
    """Forward-difference Jacobian ``df/dx`` into ``J``, one evaluation per colour (``f``
    the model's function or its address)."""
    f = as_function(f)
    n = x.shape[0]
    n_colors = 0
    for j in range(n):
        n_colors = max(n_colors, colors[j] + 1)
    for i in range(n):
        for j in range(n):
            J[i, j] = 0.0
    xs = x.copy()
    for c in range(n_colors):
        for j in range(n):
            if colors[j] == c:
                xs[j] = x[j] + 1.0e-8 * max(abs(x[j]), scale[j])
        f(t, xs, u, p, work, ybuf)
        for j in range(n):
            if colors[j] == c:
                h = 1.0e-8 * max(abs(x[j]), scale[j])
                xs[j] = x[j]
                for i in range(n):
                    if pattern[i, j]:
                        J[i, j] = (work[i] - f0[i]) / h


@jit
def lu_factor(A, piv):
    """In-place LU with partial pivoting; returns False if singular. Zeros of the pivot row
    and of the multipliers are skipped (a circuit's matrix is sparse; the result is the
    same to the last bit)."""
    n = A.shape[0]
    cols = np.empty(n, dtype=np.int64)
    for k in range(n):
        m = k
        amax = abs(A[k, k])
        for i in range(k + 1, n):
            if abs(A[i, k]) > amax:
                amax = abs(A[i, k])
                m = i
        piv[k] = m
        if amax == 0.0:
            return False
        if m != k:
            for j in range(n):
                tmp = A[k, j]
                A[k, j] = A[m, j]
                A[m, j] = tmp
        nc = 0
        for j in range(k + 1, n):
            if A[k, j] != 0.0:
                cols[nc] = j
                nc += 1
        for i in range(k + 1, n):
            A[i, k] /= A[k, k]
            fk = A[i, k]
            if fk != 0.0:
                for c in range(nc):
                    j = cols[c]
                    A[i, j] -= fk * A[k, j]
    return True


@jit
def lu_solve(A, piv, b):
    """Solve in place with the factors of :func:`lu_factor`."""
    n = A.shape[0]
    for k in range(n):
        m = piv[k]
        if m != k:
            tmp = b[k]
            b[k] = b[m]
            b[m] = tmp
    for i in range(n):
        s = b[i]
        for j in range(i):
            s -= A[i, j] * b[j]
        b[i] = s
    for i in range(n - 1, -1, -1):
        s = b[i]
        for j in range(i + 1, n):
            s -= A[i, j] * b[j]
        b[i] = s / A[i, i]


@inline
def time_derivative(f, t, x, u, p, f0, ft, work, ybuf, timed, dt_time):
    """``df/dt`` into ``ft`` by a forward difference of ``dt_time`` (only a dither makes a
    model depend on time within a held increment; ``timed`` says whether it does)."""
    n = x.shape[0]
    for i in range(n):
        ft[i] = 0.0
    if timed:
        f(t + dt_time, x, u, p, work, ybuf)
        for i in range(n):
            ft[i] = (work[i] - f0[i]) / dt_time


@inline
def w_matrix(m, t, x, u, p, h, f0, G, piv, J, work, ybuf, fresh):
    """``G = I/(h gamma) - df/dx`` at ``x``, LU-factorised in place; False if singular.
    ``fresh``: ``J`` already holds ``df/dx`` at this point (a step retried after a
    rejection starts where the rejected one did: only ``h`` changed)."""
    n = x.shape[0]
    if not fresh:
        jacobian(as_function(m[0]), t, x, u, p, f0, m[1], J, work, ybuf, m[4], m[5])
    for i in range(n):
        for j in range(n):
            G[i, j] = -J[i, j]
        G[i, i] += 1.0 / (h * _GAM)
    return lu_factor(G, piv)


@inline
def stages(f, t, x, u, p, h, f0, ft, G, piv, K, xs, work, ybuf):
    """The six Rodas4 stages ``K`` of one step from ``x`` with the factorised ``G``."""
    n = x.shape[0]
    for s in range(6):
        if s == 0:
            for i in range(n):
                work[i] = f0[i]
        else:
            for i in range(n):
                acc = x[i]
                for j in range(s):
                    acc += _A6[s, j] * K[j, i]
                xs[i] = acc
            f(t + _ALPHA[s] * h, xs, u, p, work, ybuf)
        for i in range(n):
            acc = work[i] + h * _GAMMA[s] * ft[i]
            for j in range(s):
                acc += _C6[s, j] / h * K[j, i]
            K[s, i] = acc
        lu_solve(G, piv, K[s])


@jit
def workspace(n, ny):
    """Work arrays of :func:`rodas_step` for ``n`` states and ``ny`` outputs."""
    return (np.empty(n), np.empty(n), np.empty(n), np.empty(n), np.empty(ny),
            np.empty((n, n)), np.empty((n, n)), np.zeros((6, n)), np.empty(n, dtype=np.int64))


@jit
def rodas_step(m, t, X, u, P, h, rtol, Xnew, own_jacobian, ws, D, retry=False):
    """One Rodas4 step of size ``h`` for every row of ``X`` (a copy of the state per row of
    packed parameters ``P``); returns the scaled error norm of row 0 (inf if not finite).

    Row 0 is the trajectory whose error controls the step; the other rows take the same
    step, so that differences between rows are smooth in the parameters (internal
    numerical differentiation: a sensitivity is a difference of rows). With
    ``own_jacobian`` each row uses its own Jacobian (the exact Rodas4 map of that row);
    otherwise they share row 0's factorised ``G`` and cost six right-hand sides a step.
    ``ws`` is the work space of :func:`workspace`; ``D`` (rows x 2 x n, or no rows) takes
    each row's dense-output coefficients ``c2, c3``. ``retry``: the previous call was this
    step rejected, so row 0's Jacobian in ``ws`` is still the one at ``X[0]`` (a rejection
    costs the new step's stages only; a quarter of a circuit's steps are rejected where
    commands switch and pistons reach their stops).
    """
    rows, n = X.shape
    dense_out = D.shape[0] > 0
    f, scale = as_function(m[0]), m[1]
    f0, ft, work, xs, ybuf, J, G, K, piv = ws
    err = 0.0
    for r in range(rows):
        x = X[r]
        p = P[r]
        f(t, x, u, p, f0, ybuf)
        time_derivative(f, t, x, u, p, f0, ft, work, ybuf, m[2], m[3])
        if r == 0 or own_jacobian:
            fresh = retry and r == 0 and (rows == 1 or not own_jacobian)
            if not w_matrix(m, t, x, u, p, h, f0, G, piv, J, work, ybuf, fresh):
                return np.inf
        stages(f, t, x, u, p, h, f0, ft, G, piv, K, xs, work, ybuf)
        for i in range(n):
            acc = x[i]
            for s in range(6):
                acc += _M[s] * K[s, i]
            Xnew[r, i] = acc
            if not math.isfinite(acc):
                return np.inf
            if r == 0:
                # Stiffly accurate: the error estimate is the last stage.
                sk = rtol * scale[i] + rtol * max(abs(x[i]), abs(acc))
                e = K[5, i] / sk
                err += e * e
        if r == 0:
            err = math.sqrt(err / n)
            if err > 1.0:
                return err   # rejected: the other rows need not be computed
        if dense_out:
            for i in range(n):
                c2 = 0.0
                c3 = 0.0
                for s in range(5):
                    c2 += _D2[s] * K[s, i]
                    c3 += _D3[s] * K[s, i]
                D[r, 0, i] = c2
                D[r, 1, i] = c3
    return err


@jit
def advance(m, t0, t1, X, u, P, h, rtol, h_min, max_steps, stats, own_jacobian, ny):
    """Integrate every row of ``X`` in place from ``t0`` to ``t1`` with inputs ``u`` held.

    Adaptive Rodas4 steps inside the interval, controlled by row 0 (see :func:`rodas_step`);
    ``h`` is the proposed first step, and the proposed next step is returned with a status
    code. ``stats`` accumulates ``[accepted, rejected]``. Absolute tolerances are ``rtol``
    times the model's state scales; ``ny`` is the number of its outputs.
    """
    rows, n = X.shape
    Xnew = np.empty((rows, n))
    ws = workspace(n, ny)
    no_dense = np.empty((0, 2, n))
    t = t0
    h = min(h, t1 - t0)
    steps = 0
    last_rejected = False
    h_next = h
    while t < t1:
        if steps >= max_steps:
            return h_next, FAIL_STEPS
        steps += 1
        last = t + h >= t1 - 1.0e-12 * max(abs(t1), 1.0)
        hs = t1 - t if last else h
        err = rodas_step(m, t, X, u, P, hs, rtol, Xnew, own_jacobian, ws, no_dense,
                         last_rejected)
        if err <= 1.0:
            stats[0] += 1
            for r in range(rows):
                for i in range(n):
                    X[r, i] = Xnew[r, i]
            t = t1 if last else t + hs
            fac = 0.9 * (max(err, 1.0e-10)) ** -0.25
            fac = min(fac, 1.0) if last_rejected else min(fac, 5.0)
            h_new = max(hs * max(fac, 0.2), h_min)
            # A step shortened to land on t1 must not shrink the next one.
            h_next = max(h_new, h) if last else h_new
            h = h_next
            last_rejected = False
        else:
            stats[1] += 1
            fac = 0.1 if not math.isfinite(err) else max(0.9 * err ** -0.25, 0.1)
            h = hs * fac
            h_next = h
            last_rejected = True
            if h < h_min:
                return h, FAIL_STEP if math.isfinite(err) else FAIL_NAN
    return h_next, OK


@jit
def run(m, X0, t0, dt, U, P, rtol, h_min, max_steps, decim, Y, X, stats, max_total,
        own_jacobian):
    """Integrate every row of ``X0`` (one per row of ``P``, see :func:`rodas_step`) over
    ``len(U)`` increments of ``dt``, inputs ``U[k]`` held on each.

    Outputs are written every ``decim`` increments into ``Y[r]`` (and states into ``X[r]``),
    the first row at ``t0``. ``max_total`` bounds the solver steps counted in ``stats`` (0: no
    bound). Returns ``(status, increments done)``.
    """
    n_inc = U.shape[0]
    rows, n = X0.shape
    ny = Y.shape[2]
    f = as_function(m[0])
    x = X0.copy()
    dx = np.empty(n)
    h = dt
    for r in range(rows):
        f(t0, x[r], U[0], P[r], dx, Y[r, 0])
        X[r, 0, :] = x[r]
    row = 1
    for k in range(n_inc):
        t = t0 + k * dt
        h, status = advance(m, t, t + dt, x, U[k], P, h, rtol, h_min, max_steps, stats,
                            own_jacobian, ny)
        if status != OK:
            return status, k
        if max_total > 0 and stats[0] + stats[1] > max_total:
            return FAIL_BUDGET, k + 1
        if (k + 1) % decim == 0:
            kk = min(k + 1, n_inc - 1)
            for r in range(rows):
                f(t + dt, x[r], U[kk], P[r], dx, Y[r, row])
                X[r, row, :] = x[r]
            row += 1
    return OK, n_inc


@jit
def run_dense(m, X0, t0, dt, U, P, rtol, h_min, max_steps, decim, Y, X, stats, max_total,
              own_jacobian):
    """:func:`run` with steps free of the increments: over every stretch of increments
    whose inputs are equal the steps follow the error control alone (they land on the
    stretch's end, where an input changes), and the outputs every ``decim`` increments come
    from the method's dense output. Where the solution is smooth, a step spans many
    outputs; ``max_steps`` bounds the steps per increment on average. Same arguments and
    returns as :func:`run`."""
    # A compiled loop (numba): its stages share a dozen local arrays, and splitting it would
    # pass them through calls in the innermost loop; long on purpose.
    n_inc = U.shape[0]
    rows, n = X0.shape
    ny = Y.shape[2]
    f = as_function(m[0])
    x = X0.copy()
    Xnew = np.empty((rows, n))
    D = np.empty((rows, 2, n))
    xs = np.empty(n)
    dx = np.empty(n)
    ws = workspace(n, ny)
    for r in range(rows):
        f(t0, x[r], U[0], P[r], dx, Y[r, 0])
        X[r, 0, :] = x[r]
    n_out = Y.shape[1] - 1
    row = 1
    h = dt
    k = 0
    while k < n_inc:
        k_end = k + 1
        while k_end < n_inc:
            same = True
            for j in range(U.shape[1]):
                if U[k_end, j] != U[k, j]:
                    same = False
                    break
            if not same:
                break
            k_end += 1
        u = U[k]
        t = t0 + k * dt
        t1 = t0 + k_end * dt
        steps = 0
        last_rejected = False
        while t < t1:
            if steps >= max_steps * (k_end - k):
                return FAIL_STEPS, k
            steps += 1
            last = t + h >= t1 - 1.0e-12 * max(abs(t1), 1.0)
            hs = t1 - t if last else h
            err = rodas_step(m, t, x, u, P, hs, rtol, Xnew, own_jacobian, ws, D,
                             last_rejected)
            if err <= 1.0:
                stats[0] += 1
                t_new = t1 if last else t + hs
                # Outputs inside (t, t_new] from the dense output.
                while row <= n_out and t0 + row * decim * dt <= t_new + 1.0e-12 * dt:
                    kk = min(row * decim, n_inc - 1)
                    s = (row * decim * dt + t0 - t) / hs
                    if s > 1.0:
                        s = 1.0
                    for r in range(rows):
                        for i in range(n):
                            xs[i] = x[r, i] + s * (Xnew[r, i] - x[r, i] + (1.0 - s)
                                                   * (D[r, 0, i] + s * D[r, 1, i]))
                        f(t0 + row * decim * dt, xs, U[kk], P[r], dx, Y[r, row])
                        X[r, row, :] = xs
                    row += 1
                for r in range(rows):
                    for i in range(n):
                        x[r, i] = Xnew[r, i]
                t = t_new
                fac = 0.9 * (max(err, 1.0e-10)) ** -0.25
                fac = min(fac, 1.0) if last_rejected else min(fac, 5.0)
                h_new = max(hs * max(fac, 0.2), h_min)
                h = max(h_new, h) if last else h_new
                last_rejected = False
            else:
                stats[1] += 1
                fac = 0.1 if not math.isfinite(err) else max(0.9 * err ** -0.25, 0.1)
                h = hs * fac
                last_rejected = True
                if h < h_min:
                    return (FAIL_STEP if math.isfinite(err) else FAIL_NAN), k
            if max_total > 0 and stats[0] + stats[1] > max_total:
                return FAIL_BUDGET, k
        k = k_end
    return OK, n_inc




@jit
def advance_bounded(m, t0, t1, X, u, P, h, rtol, max_steps, stats, ny):
    """Integrate every row of ``X`` in place from ``t0`` to ``t1`` (inputs ``u`` held) in
    Rodas4 steps of at most ``h``, at most ``max_steps`` of them tried: the bounded work of a
    real-time increment. Steps of ``h`` are error-controlled as in :func:`advance` (a switch
    or a stop asks for shorter ones); once the steps left would only just reach ``t1``, each
    is taken whatever its error. Returns a status code; only a state that stops being
    finite fails (the state is then left as it was)."""
    rows, n = X.shape
    Xnew = np.empty((rows, n))
    X0 = X.copy()
    ws = workspace(n, ny)
    no_dense = np.empty((0, 2, n))
    h_max = h
    t = t0
    tried = 0
    last_rejected = False
    while t < t1:
        left = t1 - t
        budget = max_steps - tried
        # No room for a rejection: the steps left only just reach t1 (or one is left).
        force = budget == 1 or budget * h <= left * (1.0 + 1.0e-9)
        if force:
            h = left / budget
        tried += 1
        last = t + h >= t1 - 1.0e-12 * max(abs(t1), 1.0)
        hs = left if last else h
        err = rodas_step(m, t, X, u, P, hs, rtol, Xnew, False, ws, no_dense, last_rejected)
        if not math.isfinite(err) and force:
            X[:, :] = X0
            return FAIL_NAN
        if err <= 1.0 or force:
            stats[0] += 1
            X[:, :] = Xnew
            t = t1 if last else t + hs
            fac = 0.9 * (max(err, 1.0e-10)) ** -0.25
            fac = min(fac, 1.0) if last_rejected else min(fac, 5.0)
            h = min(max(hs * max(fac, 0.2), 1.0e-12), h_max)
            last_rejected = False
        else:
            stats[1] += 1
            h = hs * (0.1 if not math.isfinite(err) else max(0.9 * err ** -0.25, 0.1))
            last_rejected = True
    return OK
