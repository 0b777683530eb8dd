"""What the main job's duty cycles share (the Fig. 1 circuit's, :mod:`.fig1`, and the
excavator's, :mod:`.excavator`): an operator's cycle written as ``(t, input, value)``
changes, given to the simulator as its live ``inputs.<name>`` parameters at their instants,
or held on a time grid for the offline twin; and the 20 ms mean that takes a bench
sensor's noise out of what a run is judged on.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np


def schedule(duty: Sequence[tuple]) -> list[tuple[float, str, dict]]:
    """A duty cycle as the simulator's parameter events, those of one instant together."""
    out: dict[float, dict] = {}
    for t, name, value in duty:
        out.setdefault(float(t), {})[f'inputs.{name}'] = float(value)
    return [(t, 'simulator', values) for t, values in sorted(out.items())]


def held_inputs(t: np.ndarray, duty: Sequence[tuple], start: Mapping[str, float]
                ) -> dict[str, np.ndarray]:
    """Every input of a duty cycle on the times ``t`` [s from the cycle's start]."""
    out = {}
    for name, v0 in start.items():
        v = np.full(np.shape(t), float(v0))
        for te, n, value in sorted(duty, key=lambda e: e[0]):
            if n == name:
                v[t >= te] = value
        out[name] = v
    return out


def recorder_topics(topics: Sequence[str], keep: Sequence[str]) -> list[str]:
    """Of a circuit's recorded ``topics``, those a duty cycle's bag keeps: the suite's
    measurements (which an orchestrated simulator waits to see read) and ``keep``, what
    its analysis reads. Every message costs each node a callback: fewer make the runs
    beside the paper's campaign lighter."""
    wanted = set(keep)
    return [t for t in topics if t in wanted or not (t.startswith(('loads/', 'energy/'))
                                                     or t == 'controller/state')]


def mean20(t: np.ndarray, x: np.ndarray) -> np.ndarray:
    """20 ms centred moving average (the pressure sensors' noise out)."""
    from hydropump_sim.metrics import moving_average
    k = max(1, int(round(0.02 / float(np.median(np.diff(t))))))
    return moving_average(x, k) if k > 1 else x


def filled(t: np.ndarray, v: np.ndarray) -> np.ndarray:
    """A topic published less often than the grid (the energies: every 10 ms) on every
    sample, linear between its own (the energies' sum is kept: they share their times)."""
    ok = np.isfinite(v)
    return np.interp(t, t[ok], v[ok]) if ok.any() else v
