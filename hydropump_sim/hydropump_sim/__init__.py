"""hydropump_sim: plant library of an electro-hydraulic variable-displacement axial-piston pump
with mechanical feedback (the paper's fine model, simplified model and linear analysis).

Public API (stable):

- :func:`load_params` - validated parameters from a params file such as ``config/pump.yaml``;
- :func:`simulate` - time response of the fine or simplified model;
- :func:`equilibrium` - trim at any operating point;
- :func:`linearize`, :func:`paper_linear`, :func:`transfer_matrix`, :func:`modal_analysis`,
  :func:`singular_perturbation_check` - linear analysis (eqs. 14-18, section IV);
- :class:`Simulator` - fixed-increment stepper for the ROS simulator.

Pure Python (numpy, scipy, numba): nothing here imports ROS. The linear-analysis names load
on first use, so a node that only steps the model does not pay for python-control (a second
per process).
"""

import importlib

from .params import load_params, ParamError, Params
from .simulate import IntegrationError, IntegratorConfig, SimResult, simulate, Simulator
from .trim import Equilibrium, equilibrium, TrimError

_LAZY = {name: 'linear' for name in ('linearize', 'modal_analysis', 'paper_linear',
                                     'singular_perturbation_check', 'transfer_matrix')}

__all__ = [
    'Equilibrium', 'IntegrationError', 'IntegratorConfig', 'ParamError', 'Params', 'SimResult',
    'Simulator', 'TrimError', 'equilibrium', 'linearize', 'load_params', 'modal_analysis',
    'paper_linear', 'simulate', 'singular_perturbation_check', 'transfer_matrix',
]


def __getattr__(name):
    if name in _LAZY:
        value = getattr(importlib.import_module(f'.{_LAZY[name]}', __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f'module {__name__!r} has no attribute {name!r}')


def __dir__():
    return __all__
