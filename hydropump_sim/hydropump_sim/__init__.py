"""hydropump_sim: plant library of an electro-hydraulic variable-displacement axial-piston pump
with mechanical feedback (the paper's fine model, simplified model and linear analysis).

Public API (stable):

- :func:`load_params` - validated parameters from a params file such as ``config/pump.yaml``;
  :func:`load_circuit` - a circuit from its YAML file;
- :class:`Model` - the one model interface: the paper's plant (:class:`PumpModel`) and
  every circuit implement it, and everything below runs either;
- :func:`simulate` - time response (:func:`held`: a step schedule as an input), a
  :class:`Result` indexed by name; :class:`Simulator` - the fixed-increment stepper of the
  ROS simulator;
- :func:`equilibrium` - the paper plant's steady state at any operating point;
  :func:`steady_state` - any model's;
- :func:`linearize`, :func:`transfer_matrix`, :func:`modal_analysis` - linear analysis of
  any model; :mod:`hydropump_sim.paper` - the paper's closed forms (eqs. 14-18),
  :func:`paper_linear`, :func:`singular_perturbation_check` among them.

Pure Python (numpy, scipy, numba): nothing here imports ROS. The model and the linear
analysis load on first use, so a node that only reads parameters (the controller, the
recorder) does not pay for numba and scipy, nor a node that only steps the model for
python-control (about a second each per process).
"""

import importlib
import sys
import types

from .params import load_params, ParamError, Params

_LAZY = {**{name: 'linear' for name in ('linearize', 'modal_analysis', 'transfer_matrix')},
         **{name: 'paper' for name in ('paper_linear', 'singular_perturbation_check')},
         **{name: 'simulate' for name in ('IntegrationError', 'IntegratorConfig', 'SimResult',
                                          'Simulator')},
         **{name: 'system' for name in ('Model', 'Result', 'SteadyState')},
         'PumpModel': 'plant_model', 'load_circuit': 'circuit', 'held': 'inputs',
         'steady_state': 'steady',
         **{name: 'trim' for name in ('Equilibrium', 'equilibrium', 'TrimError')}}

__all__ = [
    'Equilibrium', 'IntegrationError', 'IntegratorConfig', 'Model', 'ParamError', 'Params',
    'PumpModel', 'Result', 'SimResult', 'Simulator', 'SteadyState', 'TrimError', 'equilibrium',
    'held', 'linearize', 'load_circuit', 'load_params', 'modal_analysis', 'paper_linear',
    'simulate', 'singular_perturbation_check', 'steady_state', 'transfer_matrix',
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
