"""Fixtures of the pure tests: the controller configuration and the bench sensor profile."""

import pytest

from ..conftest import ROOT


@pytest.fixture(scope='module')
def cfg(params):
    from hydropump_ctrl.control.schema import load_config
    return load_config(ROOT / 'config' / 'controller.yaml', current_limits=params.I_limits)


@pytest.fixture(scope='module')
def bench():
    from hydropump_sim.sensors import load_profile
    return load_profile(ROOT / 'config' / 'bench.yaml')
