"""Model functions: packed parameters, state and output names, ``rhs`` and ``outputs``.

The model holds no state. ``rhs(t, x, u, params)`` follows python-control's ``nlsys``
convention; the equations themselves live in :mod:`hydropump_sim._core`.
"""

from __future__ import annotations

import numpy as np

from . import _core as c
from .params import Params

MODELS = {'fine': c.FINE, 'simplified': c.SIMPLIFIED, 'simplified_Kc': c.SIMPLIFIED_KC}
BRANCHES = {None: 0.0, 'natural': 0.0, 'pos': 1.0, 'neg': -1.0}

FINE_STATES = ('x_c', 'v_c', 'x_a', 'v_a', 'P_a', 'P_l')
FINE_UNITS = ('m', 'm/s', 'm', 'm/s', 'Pa', 'Pa')
SIMPLIFIED_STATES = ('x_a', 'P_l')
OUTPUTS = ('I_s', 'x_c', 'v_c', 'x_a', 'v_a', 'P_a', 'P_l', 'Q_p', 'Q_a', 'q_l', 'Q_load',
           'Q_relief')
OUTPUT_UNITS = ('A', 'm', 'm/s', 'm', 'm/s', 'Pa', 'Pa', 'm^3/s', 'm^3/s', 'm^3/s', 'm^3/s',
                'm^3/s')
INPUTS = ('i_s', 'P_u', 'xi_u', 'f_p')
INPUT_UNITS = ('A', 'Pa', '-', 'Hz')


def model_code(model: str) -> int:
    """Translate a model name into its kernel code, with a clear error."""
    try:
        return MODELS[model]
    except KeyError:
        raise ValueError(f'unknown model {model!r}: choose one of {", ".join(MODELS)}') \
            from None


def pack(params: Params, model: str = 'fine', branch: str | None = None) -> np.ndarray:
    """Packed parameter vector for the kernels (SI).

    Parameters
    ----------
    params : Params
        Validated plant parameters.
    model : {'fine', 'simplified', 'simplified_Kc'}
        Which equations to evaluate.
    branch : {None, 'pos', 'neg'}
        Force the pilot-valve law of eq. 4 to one side of ``x_c = 0`` (one-sided
        linearisation, docs/reference.md I2); ``None`` follows the sign of ``x_c``.
    """
    f, pu, sp, ac, pl, ln, rl, inp = (params.fluid, params.pump, params.spool, params.actuator,
                                      params.plate, params.line, params.relief, params.input)
    p = np.zeros(c.N_P)
    p[c.P_BETA] = f.beta
    p[c.P_ALPHA] = f.alpha_air
    p[c.P_PATM] = f.p_atm
    p[c.P_PT] = f.P_T
    p[c.P_FLOOR] = float(f.pressure_floor)
    p[c.P_DPFLOOR] = f.dp_floor
    p[c.P_VP] = pu.V_p
    p[c.P_STROKE] = params.stroke_scale
    p[c.P_XASTOP] = params.x_a_stop
    p[c.P_DISPCLIP] = float(pu.disp_clip)
    p[c.P_MC] = sp.m_c
    p[c.P_KC] = sp.K_c
    p[c.P_KA] = sp.K_a
    p[c.P_PHI] = sp.phi_s
    p[c.P_XCMAX] = sp.x_c_max
    p[c.P_CC] = sp.c_c
    p[c.P_FCC] = sp.F_coul_c
    p[c.P_VEPSC] = sp.v_eps_c
    p[c.P_KSTOPC] = sp.k_stop_c
    p[c.P_CSTOPC] = sp.c_stop_c
    p[c.P_SA] = ac.S_a
    p[c.P_VA0] = ac.V_a0
    p[c.P_VAMIN] = ac.V_a_min
    p[c.P_PABAR] = ac.P_a_bar
    p[c.P_MUA] = ac.mu_a
    p[c.P_DPCRA] = ac.dp_cr_a
    p[c.P_GLEAK] = ac.G_leak_a
    p[c.P_MA] = pl.m_a
    p[c.P_KB] = pl.K_b
    p[c.P_SD] = pl.S_d
    p[c.P_CA] = pl.c_a
    p[c.P_FCA] = pl.F_coul_a
    p[c.P_VEPSA] = pl.v_eps_a
    p[c.P_KSTOPA] = pl.k_stop_a
    p[c.P_CSTOPA] = pl.c_stop_a
    p[c.P_VL] = ln.V_l
    p[c.P_PLBAR] = ln.P_l_bar
    p[c.P_GAMMA] = ln.gamma_u
    p[c.P_MUU] = ln.mu_u
    p[c.P_DPCRU] = ln.dp_cr_u
    p[c.P_RELIEF] = float(rl.enabled)
    p[c.P_PCRACK] = rl.p_crack
    p[c.P_PFULL] = rl.p_full
    p[c.P_QFULL] = rl.q_full
    p[c.P_DITHA] = inp.dither_amp
    p[c.P_DITHF] = inp.dither_freq
    p[c.P_TAUS] = inp.tau_s if model == 'fine' else 0.0
    p[c.P_IMIN] = sp.I_min
    p[c.P_IMAX] = sp.I_max
    p[c.P_MODEL] = model_code(model)
    try:
        p[c.P_BRANCH] = BRANCHES[branch]
    except KeyError:
        raise ValueError(f'unknown branch {branch!r}: choose pos or neg') from None
    return p


def state_names(params: Params, model: str = 'fine') -> tuple[str, ...]:
    """Names of the states of ``model`` (the fine model gains ``i`` with ``tau_s > 0``)."""
    if model != 'fine':
        return SIMPLIFIED_STATES
    return FINE_STATES + (('i',) if params.input.tau_s > 0.0 else ())


def nominal_inputs(params: Params, i_s: float = 0.0) -> np.ndarray:
    """Input vector ``[i_s, P_u, xi_u, f_p]`` at the parameter file's operating point."""
    return np.array([i_s, params.line.P_u, params.line.xi_u, params.pump.f_p])


def rhs(t: float, x, u, params: Params, model: str = 'fine', branch: str | None = None,
        p: np.ndarray | None = None) -> np.ndarray:
    """State derivative ``dx/dt``.

    Parameters
    ----------
    t : float
        Time [s].
    x : array_like, shape (n,)
        State, see :func:`state_names` (SI, gauge pressures).
    u : array_like, shape (4,)
        ``[i_s, P_u, xi_u, f_p]`` in A, Pa, -, Hz; ``i_s`` is the variation of eq. 2.
    params : Params
    model, branch : str
        See :func:`pack`. ``p`` may pass a pre-packed vector instead.

    Returns
    -------
    ndarray, shape (n,)
    """
    p = pack(params, model, branch) if p is None else p
    x = np.asarray(x, dtype=float)
    dx = np.empty_like(x)
    c.evaluate(float(t), x, np.asarray(u, dtype=float), p, dx, np.empty(c.N_Y))
    return dx


def outputs(t: float, x, u, params: Params, model: str = 'fine', branch: str | None = None,
            p: np.ndarray | None = None) -> dict[str, float]:
    """Outputs (``OUTPUTS`` names, SI) at one state, as a dictionary."""
    p = pack(params, model, branch) if p is None else p
    x = np.asarray(x, dtype=float)
    y = np.empty(c.N_Y)
    c.evaluate(float(t), x, np.asarray(u, dtype=float), p, np.empty_like(x), y)
    return dict(zip(OUTPUTS, y.tolist()))


def pump_flow(params: Params, x_a, f_p: float | None = None) -> np.ndarray:
    """Pump flow ``Q_p`` of eq. 8 [m^3/s] for plate positions ``x_a`` [m] (array or number),
    in the parameters' ``flow_map`` reading, with ``disp_clip``; ``f_p`` [Hz] defaults to the
    parameter file's shaft speed."""
    p = pack(params)
    f = params.pump.f_p if f_p is None else float(f_p)
    x = np.asarray(x_a, dtype=float)
    out = np.array([c.pump_flow(float(v), f, p) for v in x.ravel()]).reshape(x.shape)
    return out if out.ndim else float(out)
