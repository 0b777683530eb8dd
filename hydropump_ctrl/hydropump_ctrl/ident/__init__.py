"""Identification of the current-to-flow path (section V of the paper, eqs. 19-20).

The FOPDT model ``G(s) = G0 / (1 + tau s) exp(-s t_d)`` is fitted to recordings of the solenoid
current and the line flow, by the paper's procedure or by a robust method; several data sets
are pooled as the paper does and fitted jointly. Details and the JSON schema:
``docs/identification.md``.

Modules, each building only on those above it:

- :mod:`.errors` - :class:`FitError`, :class:`PlausibilityError` (bags' own errors are
  :mod:`hydropump_ctrl.bag`'s: :class:`BagError`, :class:`BagReadError`);
- :mod:`.plausibility` - a recording checked against the pump before any fit (units,
  message types, two runs in one bag, length);
- :mod:`.model` - eq. 19 and its exact sampled form;
- :mod:`.signals` - the paper's units, data checks, bounds, dither lines, steps;
- :mod:`.diagnostics` - residual tests, covariance, flags, :class:`FopdtFit`;
- :mod:`.robust`, :mod:`.paper` - the two methods;
- :mod:`.fit` - one record: :func:`fit_fopdt` (arrays), :func:`fit_recording`;
- bags are read and written in one place, :mod:`hydropump_ctrl.bag`;
- :mod:`.recording` - :class:`Recording`, bags decoded into named SI signals, ``.npz``;
- :mod:`.pooling` - several sets: :func:`fit_recordings`, :func:`fit_bags`, the joint fit;
- :mod:`.report` - tables, JSON, Markdown, Fig. 5 and 6;
- :mod:`.synthetic` - closed-form test data with a known truth (not imported here).

Beyond eq. 19 (imported from their modules; they need the plant library's simulator):

- :mod:`.matrix` - the whole of eq. 16 from bags (``hydropump fit --matrix``);
- :mod:`.calibrate` - grey-box calibration of the fine model (``hydropump calibrate``,
  ``hydropump validate``), a package: data, engine, problem, start values, uncertainty
  (which parameters the data determine), writers;
- :mod:`.design` - experiment design from the calibration's uncertainty analysis.

Pure Python: nothing here imports ROS.
"""

from ..bag import BagError, BagReadError, list_topics, match_topic, write_bag
from .diagnostics import FLAG_TEXT, FopdtFit
from .errors import FitError, PlausibilityError
from .fit import fit_fopdt, fit_recording, METHODS
from .model import coefficients, fopdt_response, PAPER, PARAMS
from .pooling import fit_bags, fit_joint, fit_recordings, Identification, pool, Pooled
from .recording import read_recording, read_recordings, Recording, recording_to_bag, SIGNALS
from .report import format_table, to_dict, to_json, write_report
from .signals import detect_dither, Dither, load_default_params, normalise

__all__ = [
    'BagError', 'BagReadError', 'Dither', 'FLAG_TEXT', 'FitError', 'FopdtFit', 'Identification',
    'METHODS',
    'PAPER', 'PARAMS', 'PlausibilityError', 'Pooled', 'Recording', 'SIGNALS', 'coefficients',
    'detect_dither',
    'fit_bags', 'fit_fopdt', 'fit_joint', 'fit_recording', 'fit_recordings', 'fopdt_response',
    'format_table', 'list_topics', 'load_default_params', 'match_topic', 'normalise', 'pool',
    'read_recording', 'read_recordings', 'recording_to_bag', 'to_dict', 'to_json',
    'write_bag', 'write_report',
]
