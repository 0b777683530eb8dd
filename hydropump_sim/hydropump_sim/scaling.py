"""Conversions between SI signals and the paper's normalised ones (only at the edges).

The paper normalises the current to the range that spans the displacement and the flow to
``V_p f_p``, so that a full-range gain ``G0`` is 100 (% of flow per full current range).
"""

from __future__ import annotations

import numpy as np

from .params import Params


def current_for_displacement(params: Params, displacement):
    """Absolute solenoid current [A] whose steady state is ``displacement`` (0..1).

    Eqs. 8 and 10 with ``x_c = 0``: ``x_a = phi_s i_s / K_a``.
    """
    lo, hi = params.current_range
    return lo + (hi - lo) * np.asarray(displacement, dtype=float)


def displacement_of_current(params: Params, current):
    """Steady-state displacement fraction (0..1) of an absolute current [A]."""
    lo, hi = params.current_range
    return (np.asarray(current, dtype=float) - lo) / (hi - lo)


def current_to_variation(params: Params, current):
    """Absolute current ``I_s`` [A] to the variation ``i_s`` of eq. 2 [A]."""
    return np.asarray(current, dtype=float) - params.I_nominal


def flow_percent(params: Params, flow):
    """Flow [m^3/s] in % of ``V_p f_p`` at the nominal shaft speed."""
    return 100.0 * np.asarray(flow, dtype=float) / params.Q_max
