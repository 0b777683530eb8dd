"""Shared fixtures: the reference parameter set and ROS environment hygiene."""

import os
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PUMP_YAML = ROOT / 'config' / 'pump.yaml'
# The reference parameter set (test data; its figures are in docs/reference.md).
REFERENCE_YAML = ROOT / 'tests' / 'data' / 'pump_reference.yaml'

# Every test process keeps DDS discovery on loopback.
os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
# Every offline circuit run of the suite proves the physical invariants
# (hydropump_sim.invariants): a run that breaks one raises.
os.environ['HYDROPUMP_STRICT_INVARIANTS'] = '1'


@pytest.fixture(scope='session')
def params():
    from hydropump_sim import load_params
    return load_params(PUMP_YAML)

# Property tests: CI runs a fixed (derandomised) set; HYPOTHESIS_PROFILE=explore searches more.
try:
    from hypothesis import settings as _hs
    _hs.register_profile('ci', derandomize=True, deadline=None)
    _hs.register_profile('explore', max_examples=400, deadline=None)
    _hs.load_profile(os.environ.get('HYPOTHESIS_PROFILE', 'ci'))
except ImportError:  # pragma: no cover
    pass
