"""hydropump_sim: plant library of an electro-hydraulic variable-displacement axial-piston pump
with mechanical feedback (the paper's fine model, simplified model and linear analysis).

Public API (stable):

- :func:`load_params` - validated parameters from a params file such as ``config/pump.yaml``;
- :func:`simulate` - time response of the fine or simplified model (:func:`held`: a step
  schedule as an input);
- :func:`equilibrium` - trim at any operating point;
- :func:`linearize`, :func:`paper_linear`, :func:`transfer_matrix`, :func:`modal_analysis`,
  :func:`singular_perturbation_check` - linear analysis (eqs. 14-18, section IV);
- :class:`Simulator` - fixed-increment stepper for the ROS simulator.

Pure Python (numpy, scipy, numba): nothing here imports ROS. The model and the linear
analysis load on first use, so a node that only reads parameters (the controller, the
recorder) does not pay for numba and scipy, nor a node that only steps the model for
python-control (about a second each per process).
"""

import importlib
import sys
import types

from .params import load_params, ParamError, Params

_LAZY = {**{name: 'linear' for name in ('linearize', 'modal_analysis', 'paper_linear',
                                        'singular_perturbation_check', 'transfer_matrix')},
         **{name: 'simulate' for name in ('IntegrationError', 'IntegratorConfig', 'SimResult',
                                          'Simulator')},
         'held': 'inputs',
         **{name: 'trim' for name in ('Equilibrium', 'equilibrium', 'TrimError')}}

__all__ = [
    'Equilibrium', 'IntegrationError', 'IntegratorConfig', 'ParamError', 'Params', 'SimResult',
    'Simulator', 'TrimError', 'equilibrium', 'held', 'linearize', 'load_params', 'modal_analysis',
    'paper_linear', 'simulate', 'singular_perturbation_check', 'transfer_matrix',
]


class _Package(types.ModuleType):
    # simulate() shares its name with the submodule simulate.py, which the import system sets
    # on the package when it loads it: the package keeps the function.
    @property
    def simulate(self):
        return importlib.import_module('.simulate', __name__).simulate

    @simulate.setter
    def simulate(self, value):
        pass


sys.modules[__name__].__class__ = _Package


def __getattr__(name):
    if name in _LAZY:
        value = getattr(importlib.import_module(f'.{_LAZY[name]}', __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f'module {__name__!r} has no attribute {name!r}')


def __dir__():
    return __all__
