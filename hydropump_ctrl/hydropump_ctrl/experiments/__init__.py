"""Experiments on the plant offline: the closed-loop harnesses and the judged cases.

Pure Python (nothing here imports ROS). Modules, each building only on those above it:

- :mod:`.harness` - one closed loop over any model, sensors seeing every step as the
  nodes' do (:func:`~.harness.run_loop`);
- :mod:`.closed_loop` - the paper's plant in that loop (:func:`run_closed_loop`), and the
  figures of a run;
- :mod:`.circuit_loop` - a circuit in that loop, with the controller made for it;
- :mod:`.cases` - the judged closed-loop cases, their limits as tables, and the target
  table (docs/control.md).

The demo application (its campaign, duty cycles, figures and report) is
:mod:`hydropump_ctrl.demo`; the recording plans, a file format, are
:mod:`hydropump_ctrl.plans`.
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
