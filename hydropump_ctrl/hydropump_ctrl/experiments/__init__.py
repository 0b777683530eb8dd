"""Experiments on the plant: the closed-loop harness, the judged cases and the demo campaign.

Everything an experiment needs apart from running the node graph, pure Python (nothing here
imports ROS). Modules, each building only on those above it:

- :mod:`.closed_loop` - the offline twin of the graph: fine-model simulator, sensor bank and
  a controller at its rate (:func:`run_closed_loop`), and the figures of a run;
- :mod:`.cases` - the judged closed-loop cases and the target table (docs/control.md);
- :mod:`.plots`, :mod:`.report` - the figures and the HTML report of the demo;
- :mod:`.campaign` - the demo's experiments (run through the nodes by ``hydropump-demo``),
  the plant's own answer to them, and the analysis of their bags.
"""

from .closed_loop import (
    ClosedLoopResult,
    dither_free,
    Event,
    PlantVariation,
    run_closed_loop,
    trim_current,
)

__all__ = ['ClosedLoopResult', 'Event', 'PlantVariation', 'dither_free', 'run_closed_loop',
           'trim_current']
