"""Control of the pump: Embedded Model Control, the PI baseline, excitation signals,
the parameter schema and the design tools. Pure Python: nothing here imports ROS.

Typical use (a ROS node does the same)::

    from hydropump_ctrl.control import load_config, make_controller
    ctrl = make_controller(load_config('config/controller.yaml'))
    ctrl.reset(current, first_measurements)
    command = ctrl.update(t, dt, measurements)     # absolute solenoid current [A]

See docs/control.md.
"""

from .base import Controller, MEASUREMENTS
from .emc import EMCController
from .pi import PIController
from .schema import ControllerConfig, iter_specs, load_config, MODES, validate_parameter

__all__ = ['Controller', 'ControllerConfig', 'EMCController', 'MEASUREMENTS', 'MODES',
           'PIController', 'iter_specs', 'load_config', 'make_controller', 'validate_parameter']


def make_controller(config: ControllerConfig) -> Controller:
    """The controller that ``controller.algorithm`` names (``emc`` or ``pi``)."""
    return {'emc': EMCController, 'pi': PIController}[config.controller.algorithm](config)
