"""Parameter sweeps and tolerance studies of the plant, run on Dask distributed.

- :func:`load_sweep` - a checked sweep file (plant, experiment, samples, outputs);
- :func:`run_sweep` - the runs on a local cluster or a scheduler, resumable, then
  ``runs.parquet`` and ``report.html``;
- :func:`src` - standardised regression coefficients.

Pure Python: nothing here imports ROS. See ``docs/sweeps.md``.
"""

from .engine import open_client, run_sweep, SweepResult
from .report import read_table, sensitivities, src
from .spec import load_sweep, Sweep, sweep_from_dict, SweepError

__all__ = ['Sweep', 'SweepError', 'SweepResult', 'load_sweep', 'open_client', 'read_table',
           'run_sweep', 'sensitivities', 'src', 'sweep_from_dict']
