"""Parameter sweeps and tolerance studies of the plant, run on the suite's execution layer
(:mod:`hydropump_ctrl.batch`: this process, a local Dask cluster or a scheduler).

- :func:`load_sweep` - a checked sweep file (plant, experiment, samples, outputs);
- :func:`run_sweep` - the runs where they finish soonest or where asked, resumable, then
  ``runs.parquet`` and ``report.html``;
- :func:`src` - standardised regression coefficients; :func:`sensitivities` - with the
  Sobol or Morris indices of SALib where the sample allows.

Pure Python: nothing here imports ROS. See ``docs/sweeps.md``.
"""

from .engine import open_client, run_sweep, SweepResult
from .report import read_table, sensitivities, src
from .spec import load_sweep, Sweep, sweep_from_dict, SweepError

__all__ = ['Sweep', 'SweepError', 'SweepResult', 'load_sweep', 'open_client', 'read_table',
           'run_sweep', 'sensitivities', 'src', 'sweep_from_dict']
