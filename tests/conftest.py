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


# The C pumps of tests/fmus.py (FMI 3.0 co-simulation, FMI 2.0 model exchange), built once
# per test process for the unit and the node tests.
@pytest.fixture(scope='session')
def pump3(tmp_path_factory):
    from . import fmus
    return fmus.c_pump3(tmp_path_factory.mktemp('pump3'))


@pytest.fixture(scope='session')
def pump_me(tmp_path_factory):
    from . import fmus
    return fmus.c_pump_me(tmp_path_factory.mktemp('pump_me'))

# Property tests: CI runs a fixed (derandomised) set; HYPOTHESIS_PROFILE=explore searches more.
try:
    from hypothesis import settings as _hs
    _hs.register_profile('ci', derandomize=True, deadline=None)
    _hs.register_profile('explore', max_examples=400, deadline=None)
    _hs.load_profile(os.environ.get('HYPOTHESIS_PROFILE', 'ci'))
except ImportError:  # pragma: no cover
    pass


def assert_provenance(prov: dict, files=(), words=()) -> None:
    """A report's provenance: a UTC date, the command line holding ``words``, this checkout's
    commit (when it is one), the versions, and each of ``files`` with the SHA-256 of its
    bytes as they are now (computed here, apart from the code under test)."""
    from datetime import datetime
    import hashlib
    import subprocess
    stamp = datetime.fromisoformat(prov['date'])
    assert stamp.utcoffset() is not None and stamp.utcoffset().total_seconds() == 0
    for w in words:
        assert w in prov['command'], (w, prov['command'])
    if (ROOT / '.git').exists():
        head = subprocess.run(['git', '-C', str(ROOT), 'rev-parse', 'HEAD'],
                              capture_output=True, text=True).stdout.strip()
        assert prov['commit'].split('-')[0] == head, (prov['commit'], head)
    assert {'python', 'numpy', 'scipy'} <= set(prov['versions'])
    listed = {Path(f['path']): f for f in prov['inputs']}
    for f in files:
        entry = listed[Path(f).resolve()]
        if Path(f).is_file():
            assert entry['sha256'] == hashlib.sha256(Path(f).read_bytes()).hexdigest()
