"""Compiled kernels: model equations and the Rodas4 stepper.

Everything here works on plain float arrays so that numba can compile it once and cache it.
The packed parameter vector ``p`` is built by :func:`hydropump_sim.model.pack`; its layout is
the ``P_*`` indices below. The equations are written once, in :func:`evaluate`, which returns
both the state derivative and the outputs, so the right-hand side and the outputs can never
disagree.

Models (``p[P_MODEL]``):

- ``FINE``: the 6th-order fine model, eqs. 1-9 (7th state with solenoid current dynamics);
- ``SIMPLIFIED``: eqs. 10, 12 (first line) and 9, eq. 10 as printed (drops ``K_c``);
- ``SIMPLIFIED_KC``: the same, keeping ``K_c`` in the quasi-static spool position.
"""

import math

import numba
import numpy as np

FINE, SIMPLIFIED, SIMPLIFIED_KC = 0, 1, 2

# Packed parameter vector layout.
(P_BETA, P_ALPHA, P_PATM, P_PT, P_FLOOR, P_DPFLOOR,
 P_VP, P_STROKE, P_XASTOP, P_DISPCLIP,
 P_MC, P_KC, P_KA, P_PHI, P_XCMAX, P_CC, P_FCC, P_VEPSC, P_KSTOPC, P_CSTOPC,
 P_SA, P_VA0, P_VAMIN, P_PABAR, P_MUA, P_DPCRA, P_GLEAK,
 P_MA, P_KB, P_SD, P_CA, P_FCA, P_VEPSA, P_KSTOPA, P_CSTOPA,
 P_VL, P_PLBAR, P_GAMMA, P_MUU, P_DPCRU,
 P_RELIEF, P_PCRACK, P_PFULL, P_QFULL,
 P_DITHA, P_DITHF, P_TAUS, P_IMIN, P_IMAX,
 P_MODEL, P_BRANCH, N_P) = range(52)

# Inputs: commanded current variation i_s [A], load pressure P_u [Pa], aperture xi_u [-],
# shaft frequency f_p [Hz].
U_IS, U_PU, U_XI, U_FP, N_U = range(5)

# Outputs.
(Y_IS, Y_XC, Y_VC, Y_XA, Y_VA, Y_PA, Y_PL, Y_QP, Y_QA, Y_QL, Y_QLOAD, Y_QRELIEF,
 N_Y) = range(13)

# Rodas4 (Hairer & Wanner, Solving ODEs II, sec. IV.7), in the form
#   (I/(h g) - J) k_i = f(t + a_i h, x + sum_j A_ij k_j) + sum_j C_ij k_j / h + h g_i f_t.
_GAM = 0.25
_ALPHA = np.array([0.0, 0.386, 0.21, 0.63, 1.0, 1.0])
_GAMMA = np.array([0.25, -0.1043, 0.1035, -0.0362, 0.0, 0.0])
_A = np.zeros((6, 6))
_C = np.zeros((6, 6))
_A[1, 0] = 1.544
_A[2, :2] = (0.9466785280815826, 0.2557011698983284)
_A[3, :3] = (3.314825187068521, 2.896124015972201, 0.9986419139977817)
_A[4, :4] = (1.221224509226641, 6.019134481288629, 12.53708332932087, -0.687886036105895)
_A[5, :5] = (1.221224509226641, 6.019134481288629, 12.53708332932087, -0.687886036105895, 1.0)
_C[1, 0] = -5.6688
_C[2, :2] = (-2.430093356833875, -0.2063599157091915)
_C[3, :3] = (-0.1073529058151375, -9.594562251023355, -20.47028614809616)
_C[4, :4] = (7.496443313967647, -10.24680431464352, -33.99990352819905, 11.7089089320616)
_C[5, :5] = (8.083246795921522, -7.981132988064893, -31.52159432874371, 16.31930543123136,
             -6.058818238834054)
# Stiffly accurate: the solution is the 6th stage, the error estimate is k_6.
_M = np.array([1.221224509226641, 6.019134481288629, 12.53708332932087, -0.687886036105895,
               1.0, 1.0])

# Integration status codes.
OK, FAIL_STEP, FAIL_NAN, FAIL_STEPS, FAIL_BUDGET = 0, 1, 2, 3, 4

jit = numba.njit(cache=True, fastmath=False, nogil=True)
# Helpers of the stepper, inlined into it (a call per stage costs about a fifth of a step).
inline = numba.njit(cache=True, fastmath=False, nogil=True, inline='always')


@jit
def sroot(dp, dp_cr):
    """Signed regularised square root: laminar below ``dp_cr``, ``sqrt`` above (I3)."""
    if dp_cr > 0.0:
        return dp / (dp * dp + dp_cr * dp_cr) ** 0.25
    return math.sqrt(dp) if dp > 0.0 else 0.0


@jit
def groot(dp, dp_cr, gamma):
    """Signed regularised ``dp**(1/gamma)``, linear below ``dp_cr`` (eq. 9, I3)."""
    e = 1.0 / gamma
    if dp_cr > 0.0:
        return dp * (dp * dp + dp_cr * dp_cr) ** (0.5 * (e - 1.0))
    return dp ** e if dp > 0.0 else 0.0


# Penetration, as a fraction of the stroke limit, over which an end stop's damping ramps in.
STOP_RAMP = 0.01


@jit
def stop_force(x, v, x_max, k, c):
    """Penalty end stop at ``+-x_max``: spring and damper that push and never pull.

    The damping ramps in over ``STOP_RAMP * x_max`` of penetration, so the force is continuous
    at contact (a jump there stalls any error-controlled integrator at a fast impact).
    """
    if k <= 0.0:
        return 0.0
    if x > x_max:
        pen = x - x_max
        ramp = min(pen / (STOP_RAMP * x_max), 1.0)
        return min(-k * pen - ramp * c * v, 0.0)
    if x < -x_max:
        pen = x + x_max
        ramp = min(-pen / (STOP_RAMP * x_max), 1.0)
        return max(-k * pen - ramp * c * v, 0.0)
    return 0.0


@jit
def bulk_modulus(P, p):
    """Effective bulk modulus: pure liquid, or isothermal mixture with entrained air (I4)."""
    beta = p[P_BETA]
    alpha = p[P_ALPHA]
    if alpha <= 0.0:
        return beta
    p_abs = max(P + p[P_PATM], 1.0)
    theta = alpha / (1.0 - alpha) * p[P_PATM] / p_abs
    return beta * (1.0 + theta) / (1.0 + theta * beta / p_abs)


# Relaxation time that returns a pressure pushed below absolute zero by a finite step [s].
FLOOR_RELAX = 1.0e-4


@jit
def pressure_rate(P, flow, volume, p):
    """Continuity ``dP/dt = beta/V * flow`` with the cavitation floor at absolute zero.

    Within ``dp_floor`` of absolute zero an outflow lowers the pressure ever more slowly (the
    liquid cavitates instead), and a pressure below zero relaxes back in ``FLOOR_RELAX``.
    """
    d = bulk_modulus(P, p) / volume * flow
    if p[P_FLOOR] > 0.0:
        p_abs = P + p[P_PATM]
        if d < 0.0 and p_abs < p[P_DPFLOOR]:
            d *= max(p_abs, 0.0) / p[P_DPFLOOR]
        if p_abs < 0.0:
            d -= p_abs / FLOOR_RELAX
    return d


@jit
def relief_flow(P_l, p):
    """Relief valve of Fig. 1: opening linear from ``p_crack`` to ``p_full``, orifice law."""
    if p[P_RELIEF] <= 0.0 or P_l <= p[P_PCRACK]:
        return 0.0
    opening = min((P_l - p[P_PCRACK]) / (p[P_PFULL] - p[P_PCRACK]), 1.0)
    return p[P_QFULL] * opening * math.sqrt(P_l / p[P_PFULL])


@jit
def pilot_flows(x_c, P_a, P_l, p):
    """Pilot valve, eq. 4: return ``(Q_a, Q_from_line)``, ``Q_a > 0`` out of the actuator.

    ``x_c > 0`` drains the actuator to tank; ``x_c < 0`` feeds it from the line. The branch
    can be forced (``p[P_BRANCH]`` = +1 or -1) for the one-sided linearisations (I2).
    """
    branch = p[P_BRANCH]
    if branch == 0.0:
        branch = 1.0 if x_c >= 0.0 else -1.0
    leak = p[P_GLEAK] * (P_a - p[P_PT])
    if branch > 0.0:
        return p[P_MUA] * x_c * sroot(P_a - p[P_PT], p[P_DPCRA]) + leak, 0.0
    q = p[P_MUA] * x_c * sroot(P_l - P_a, p[P_DPCRA])
    return q + leak, q


@jit
def pump_flow(x_a, f_p, p):
    """Eq. 8 (``flow_map`` reading in ``P_STROKE``), clipped to the displacement range."""
    disp = 0.5 + x_a / p[P_STROKE]
    if p[P_DISPCLIP] > 0.0:
        disp = min(max(disp, 0.0), 1.0)
    return p[P_VP] * f_p * disp


@jit
def n_states(p):
    """Number of states of the model selected in ``p``."""
    if p[P_MODEL] != FINE:
        return 2
    return 7 if p[P_TAUS] > 0.0 else 6


@jit
def evaluate(t, x, u, p, dx, y):
    """Right-hand side and outputs in one pass.

    Parameters
    ----------
    t : float
        Time [s] (dither phase).
    x : ndarray, shape (n,)
        Fine: ``[x_c, v_c, x_a, v_a, P_a, P_l(, i)]`` in m, m/s, Pa (gauge), A.
        Simplified: ``[x_a, P_l]``.
    u : ndarray, shape (4,)
        ``[i_s, P_u, xi_u, f_p]``: current variation [A], load pressure [Pa], aperture [-],
        shaft frequency [Hz].
    p : ndarray
        Packed parameters.
    dx : ndarray, shape (n,)
        Filled with the state derivative.
    y : ndarray, shape (N_Y,)
        Filled with the outputs (``Y_*`` layout).
    """
    i_ref = u[U_IS]
    if p[P_DITHA] > 0.0:
        i_ref += p[P_DITHA] * math.sin(2.0 * math.pi * p[P_DITHF] * t)
    model = p[P_MODEL]
    if model == FINE:
        x_c = x[0]
        v_c = x[1]
        x_a = x[2]
        v_a = x[3]
        P_a = x[4]
        P_l = x[5]
        if p[P_TAUS] > 0.0:
            i_s = x[6]
            dx[6] = (i_ref - i_s) / p[P_TAUS]
        else:
            i_s = i_ref
        # Eq. 1: spool; A_c = viscous + smoothed Coulomb; end stops at +-x_c_max (I13).
        F_c = (-p[P_CC] * v_c - p[P_FCC] * math.tanh(v_c / p[P_VEPSC])
               - (p[P_KC] + p[P_KA]) * x_c - p[P_KA] * x_a + p[P_PHI] * i_s
               + stop_force(x_c, v_c, p[P_XCMAX], p[P_KSTOPC], p[P_CSTOPC]))
        # Eq. 4: pilot valve; eq. 3: actuator continuity with V_a = V_a0 - S_a x_a (I14).
        Q_a, Q_in = pilot_flows(x_c, P_a, P_l, p)
        V_a = max(p[P_VA0] - p[P_SA] * x_a, p[P_VAMIN])
        # Eq. 6 with the variational pressures of eq. 7.
        F_a = (-p[P_CA] * v_a - p[P_FCA] * math.tanh(v_a / p[P_VEPSA])
               - p[P_KB] * x_a - p[P_KA] * (x_a + x_c)
               - (P_a - p[P_PABAR]) * p[P_SA] - (P_l - p[P_PLBAR]) * p[P_SD]
               + stop_force(x_a, v_a, p[P_XASTOP], p[P_KSTOPA], p[P_CSTOPA]))
        dx[0] = v_c
        dx[1] = F_c / p[P_MC]
        dx[2] = v_a
        dx[3] = F_a / p[P_MA]
        dx[4] = pressure_rate(P_a, -Q_a + p[P_SA] * v_a, V_a, p)
    else:
        x_a = x[0]
        P_l = x[1]
        i_s = i_ref
        # Eq. 10: quasi-static spool (as printed, or keeping K_c: I8), inside its stops.
        if model == SIMPLIFIED:
            x_c = p[P_PHI] * i_s / p[P_KA] - x_a
        else:
            x_c = (p[P_PHI] * i_s - p[P_KA] * x_a) / (p[P_KA] + p[P_KC])
        if p[P_KSTOPC] > 0.0:
            x_c = min(max(x_c, -p[P_XCMAX]), p[P_XCMAX])
        # Eq. 12, first line (keeps p_l S_d: I9); K_a (x_a + x_c) = phi_s i_s for eq. 10.
        P_a = p[P_PABAR] - (p[P_KB] * x_a + p[P_KA] * (x_a + x_c)
                            + (P_l - p[P_PLBAR]) * p[P_SD]) / p[P_SA]
        Q_a, Q_in = pilot_flows(x_c, P_a, P_l, p)
        v_a = Q_a / p[P_SA]
        if p[P_KSTOPA] > 0.0 and ((x_a >= p[P_XASTOP] and v_a > 0.0)
                                  or (x_a <= -p[P_XASTOP] and v_a < 0.0)):
            v_a = 0.0
        v_c = 0.0
        dx[0] = v_a
    # Eq. 8 and eq. 9 (pilot inflow only for x_c < 0), plus the relief valve.
    Q_p = pump_flow(x_a, u[U_FP], p)
    Q_load = p[P_MUU] * u[U_XI] * groot(P_l - u[U_PU], p[P_DPCRU], p[P_GAMMA])
    Q_r = relief_flow(P_l, p)
    q_l = Q_p + Q_in
    dP_l = pressure_rate(P_l, q_l - Q_load - Q_r, p[P_VL], p)
    if model == FINE:
        dx[5] = dP_l
    else:
        dx[1] = dP_l
    y[Y_IS] = p[P_IMIN] + p[P_IMAX] + i_s
    y[Y_XC] = x_c
    y[Y_VC] = v_c
    y[Y_XA] = x_a
    y[Y_VA] = v_a
    y[Y_PA] = P_a
    y[Y_PL] = P_l
    y[Y_QP] = Q_p
    y[Y_QA] = Q_a
    y[Y_QL] = q_l
    y[Y_QLOAD] = Q_load
    y[Y_QRELIEF] = Q_r


@jit
def state_scale(p, n):
    """Typical magnitude of each state, for tolerances and finite differences."""
    s = np.empty(n)
    if p[P_MODEL] == FINE:
        s[0] = p[P_XCMAX]
        s[1] = 0.1
        s[2] = p[P_XASTOP]
        s[3] = 0.1
        s[4] = 1.0e6
        s[5] = 1.0e6
        if n == 7:
            s[6] = p[P_IMAX]
    else:
        s[0] = p[P_XASTOP]
        s[1] = 1.0e6
    return s


@jit
def jacobian(t, x, u, p, f0, scale, J, work, ybuf):
    """Forward-difference Jacobian ``df/dx`` into ``J``."""
    n = x.shape[0]
    for j in range(n):
        h = 1.0e-8 * max(abs(x[j]), scale[j])
        xj = x[j]
        x[j] = xj + h
        evaluate(t, x, u, p, work, ybuf)
        x[j] = xj
        for i in range(n):
            J[i, j] = (work[i] - f0[i]) / h


@jit
def lu_factor(A, piv):
    """In-place LU with partial pivoting; returns False if singular."""
    n = A.shape[0]
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
        for i in range(k + 1, n):
            A[i, k] /= A[k, k]
            f = A[i, k]
            for j in range(k + 1, n):
                A[i, j] -= f * A[k, j]
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
def time_derivative(t, x, u, p, f0, ft, work, ybuf):
    """``df/dt`` into ``ft``: only the dither makes the system non-autonomous within a step."""
    n = x.shape[0]
    for i in range(n):
        ft[i] = 0.0
    if p[P_DITHA] > 0.0:
        dt = 1.0e-7 / max(p[P_DITHF], 1.0)
        evaluate(t + dt, x, u, p, work, ybuf)
        for i in range(n):
            ft[i] = (work[i] - f0[i]) / dt


@inline
def w_matrix(t, x, u, p, h, f0, scale, G, piv, J, work, ybuf):
    """``G = I/(h gamma) - df/dx`` at ``x``, LU-factorised in place; False if singular."""
    n = x.shape[0]
    jacobian(t, x, u, p, f0, scale, J, work, ybuf)
    for i in range(n):
        for j in range(n):
            G[i, j] = -J[i, j]
        G[i, i] += 1.0 / (h * _GAM)
    return lu_factor(G, piv)


@inline
def stages(t, x, u, p, h, f0, ft, G, piv, K, xs, work, ybuf):
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
                    acc += _A[s, j] * K[j, i]
                xs[i] = acc
            evaluate(t + _ALPHA[s] * h, xs, u, p, work, ybuf)
        for i in range(n):
            acc = work[i] + h * _GAMMA[s] * ft[i]
            for j in range(s):
                acc += _C[s, j] / h * K[j, i]
            K[s, i] = acc
        lu_solve(G, piv, K[s])


@jit
def workspace(n):
    """Work arrays of :func:`rodas_step` for ``n`` states (allocated once per interval)."""
    return (np.empty(n), np.empty(n), np.empty(n), np.empty(n), np.empty(N_Y),
            np.empty((n, n)), np.empty((n, n)), np.zeros((6, n)), np.empty(n, dtype=np.int64))


@jit
def rodas_step(t, X, u, P, h, scale, rtol, Xnew, own_jacobian, ws):
    """One Rodas4 step of size ``h`` for every row of ``X`` (a copy of the state per row of
    packed parameters ``P``); returns the scaled error norm of row 0 (inf if not finite).

    Row 0 is the trajectory whose error controls the step; the other rows take the same
    step, so that differences between rows are smooth in the parameters (internal
    numerical differentiation: a sensitivity is a difference of rows). With
    ``own_jacobian`` each row uses its own Jacobian (the exact Rodas4 map of that row);
    otherwise they share row 0's factorised ``G`` and cost six right-hand sides a step.
    ``ws`` is the work space of :func:`workspace`.
    """
    m, n = X.shape
    f0, ft, work, xs, ybuf, J, G, K, piv = ws
    err = 0.0
    for r in range(m):
        x = X[r]
        p = P[r]
        evaluate(t, x, u, p, f0, ybuf)
        time_derivative(t, x, u, p, f0, ft, work, ybuf)
        if r == 0 or own_jacobian:
            if not w_matrix(t, x, u, p, h, f0, scale, G, piv, J, work, ybuf):
                return np.inf
        stages(t, x, u, p, h, f0, ft, G, piv, K, xs, work, ybuf)
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
    return err


@jit
def advance(t0, t1, X, u, P, h, rtol, h_min, max_steps, stats, own_jacobian=False):
    """Integrate every row of ``X`` in place from ``t0`` to ``t1`` with inputs ``u`` held.

    Adaptive Rodas4 steps inside the interval, controlled by row 0 (see :func:`rodas_step`);
    ``h`` is the proposed first step, and the proposed next step is returned with a status
    code. ``stats`` accumulates ``[accepted, rejected]``. Absolute tolerances are ``rtol``
    times the state scales.
    """
    m, n = X.shape
    scale = state_scale(P[0], n)
    Xnew = np.empty((m, n))
    ws = workspace(n)
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
        err = rodas_step(t, X, u, P, hs, scale, rtol, Xnew, own_jacobian, ws)
        if err <= 1.0:
            stats[0] += 1
            for r in range(m):
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
def run(X0, t0, dt, U, P, rtol, h_min, max_steps, decim, Y, X, stats, max_total,
        own_jacobian=False):
    """Integrate every row of ``X0`` (one per row of ``P``, see :func:`rodas_step`) over
    ``len(U)`` increments of ``dt``, inputs ``U[k]`` held on each.

    Outputs are written every ``decim`` increments into ``Y[r]`` (and states into ``X[r]``),
    the first row at ``t0``. ``max_total`` bounds the solver steps counted in ``stats`` (0: no
    bound). Returns ``(status, increments done)``.
    """
    n_inc = U.shape[0]
    m, n = X0.shape
    x = X0.copy()
    dx = np.empty(n)
    h = dt
    for r in range(m):
        evaluate(t0, x[r], U[0], P[r], dx, Y[r, 0])
        X[r, 0, :] = x[r]
    row = 1
    for k in range(n_inc):
        t = t0 + k * dt
        h, status = advance(t, t + dt, x, U[k], P, h, rtol, h_min, max_steps, stats,
                            own_jacobian)
        if status != OK:
            return status, k
        if max_total > 0 and stats[0] + stats[1] > max_total:
            return FAIL_BUDGET, k + 1
        if (k + 1) % decim == 0:
            kk = min(k + 1, n_inc - 1)
            for r in range(m):
                evaluate(t + dt, x[r], U[kk], P[r], dx, Y[r, row])
                X[r, row, :] = x[r]
            row += 1
    return OK, n_inc
