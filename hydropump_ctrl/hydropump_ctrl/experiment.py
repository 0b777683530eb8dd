"""One run through the node graph (:class:`Experiment`), as every orchestrated run describes
it: the demo's campaign, its Fig. 1 duty cycle and ``hydropump record``'s plans; the
simulator's operating point of one (:func:`operating_point`); and the stop of such a run by
SIGTERM (:class:`Stopped`). Below both the plans (a file format) and the demo application
(:mod:`hydropump_ctrl.experiments`), which read it."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
import signal


class Stopped(BaseException):
    """SIGTERM: a run through the node graph stops.

    The ROS side raises it in the main thread from its signal handler, as Ctrl-C raises
    ``KeyboardInterrupt``, so that each ``finally`` on the way ends what it started (a graph's
    nodes by PID, each closing its bag); the command (``hydropump-demo``, ``hydropump
    record``) then says so in one line and exits with :attr:`EXIT_CODE`. Defined here, where
    both the ROS runners and the pure ``hydropump`` command line see it.
    """

    #: 128 + SIGTERM, as a shell reports a process that SIGTERM ended.
    EXIT_CODE = 128 + signal.SIGTERM


@dataclass
class Experiment:
    """One run through the graph: live parameters, topics to record, schedule of changes.

    Attributes
    ----------
    name, label : str
        Bag name; one line for the progress and the report.
    duration : float
        Simulated time [s], counted from the experiment's start.
    sim, ctrl : dict
        Live parameters of the simulator (the operating point, initial current and noise
        seed, applied by its ``~/reset``) and of the controller, set before the start.
    topics : list of str
        Topics the experiment needs recorded.
    events : list
        ``(t, node, {param: value})``: parameters set on a node ``t`` seconds after the start.
    preroll : float
        Simulated time [s] run before the start and not recorded, for a closed loop to settle
        on its initial reference.
    ctrl_first : dict
        Controller parameters set before ``ctrl`` (a configuration from which ``ctrl``, set
        one parameter at a time, passes the controller's checks).

    A controller change in ``events`` takes effect at the control instant ``t`` exactly (the
    graph pauses one control period before it, once the controller has answered there); a
    simulator change is held from ``t``.
    """

    name: str
    label: str
    duration: float
    sim: dict
    ctrl: dict
    topics: list
    events: list = field(default_factory=list)
    preroll: float = 0.0
    ctrl_first: dict = field(default_factory=dict)

    def bag(self, folder: str | Path) -> Path:
        """The run's bag in ``folder``: named after the experiment."""
        return Path(folder) / self.name


#: Set on the controller before an experiment's own excitation (:attr:`Experiment.ctrl_first`):
#: the controller checks each parameter against the others, one at a time, so an excitation
#: cannot always follow the one before directly (levels of 35..65 % after levels of
#: 0.4..0.6 A, or the other way round). From this configuration, a sine of zero amplitude
#: whose levels are not checked against each other, every excitation can, when its
#: ``excitation.signal`` comes last.
EXCITATION_BASE = {'excitation.amplitude': 0.0, 'excitation.offset': 0.0,
                   'excitation.relative': False, 'excitation.signal': 'sine'}


def operating_point(params, current: float, seed: int = 0, **inputs) -> dict:
    """The simulator's live parameters of an experiment: the whole operating point, since
    the graph keeps what the previous experiment left."""
    return {'initial_current': float(current), 'line.P_u': params.line.P_u,
            'line.xi_u': params.line.xi_u, 'sensors.seed': seed, **inputs}
