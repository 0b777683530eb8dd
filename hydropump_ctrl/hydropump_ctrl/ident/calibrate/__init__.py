"""Grey-box calibration of the fine model to recordings (``hydropump calibrate``,
``hydropump validate``), in the manner of MATLAB's ``nlgreyest``.

Chosen plant parameters (dotted names of ``config/pump.yaml``) are estimated by fitting the
6th-order fine model to several recordings at once. The package is laid out as scipy's
``optimize._lsq`` is:

- :mod:`.data` - recordings as the model sees them (held inputs, measured outputs, noise
  levels) and the checks of bad input;
- :mod:`.engine` - the simulations: every experiment at a parameter vector, and the
  sensitivities from copies of the plant stepped with the nominal run in one compiled loop,
  as jobs of the suite's execution layer (:mod:`hydropump_ctrl.batch`);
- :mod:`.problem` - search coordinates, ties and priors; the residuals and their Jacobian,
  with the measurement delays and offsets solved inside (variable projection);
- :mod:`.start` - start values in closed form where the data allow (eqs. 6, 9, 14);
- :mod:`.uncertainty` - standard errors, 95 % intervals, weak and singular directions;
- :mod:`.lacks` - what the model lacks: the fixed parameters ranked by how much of the
  misfit each would explain if freed, and the start of a free parameter at zero;
- :mod:`.writers` - the calibrated params file, the JSON result, the report and figures;
- :mod:`.fleet` - many pumps, each calibrated on its own bags as one task, and one table of
  every pump's parameters and standard errors;
- :mod:`.calibration` - the front end: :func:`calibrate` and :func:`validate`; this module
  only names what the package offers.

Every free parameter comes back at its best estimate with a standard error and a 95 %
interval; a poorly determined one is flagged with the combination the data determine, and
only a direction the information matrix is singular in (to working precision) is held, the
result saying so. Nothing here imports ROS.
"""

from .calibration import (
    calibrate,
    Calibration,
    fit_percent,
    fit_problem,
    Found,
    misfit_table,
    ParameterEstimate,
    prepare,
    result_of,
    validate,
)
from .data import CalibrationError, Experiment, experiment_from, noise_level
from .engine import DERIVED, params_with, simulate_experiment, tied_values
from .problem import (
    check_free,
    Coordinates,
    DELAY_MAX,
    delayed,
    LEAD_SAMPLES,
    parse_prior,
    Prior,
    Problem,
)
from .uncertainty import DETERMINED_REL_STD
from .writers import (
    fit_table,
    refuse_foreign_report,
    write_calibration_report,
    write_params,
    write_text,
    write_validation_report,
)

__all__ = ['Calibration', 'CalibrationError', 'Coordinates', 'DELAY_MAX', 'LEAD_SAMPLES',
           'DERIVED', 'DETERMINED_REL_STD', 'Experiment', 'Found', 'ParameterEstimate',
           'Prior', 'Problem', 'calibrate', 'check_free', 'delayed', 'experiment_from',
           'fit_percent', 'fit_problem', 'fit_table', 'misfit_table', 'noise_level',
           'params_with', 'parse_prior', 'prepare', 'refuse_foreign_report', 'result_of',
           'simulate_experiment', 'tied_values', 'validate', 'write_calibration_report',
           'write_params', 'write_text', 'write_validation_report']
