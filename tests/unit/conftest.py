"""Fixtures of the pure tests: the controller configuration and the bench sensor profile;
a circuit file written from its components."""

import pytest
import yaml

from ..conftest import ROOT


@pytest.fixture(scope='module')
def cfg(params):
    from hydropump_ctrl.control.schema import load_config
    return load_config(ROOT / 'config' / 'controller.yaml', current_limits=params.I_limits)


@pytest.fixture(scope='module')
def bench():
    from hydropump_sim.sensors import load_profile
    return load_profile(ROOT / 'config' / 'bench.yaml')


def write_circuit(folder, name: str, fluid: dict, components: dict):
    """A circuit file ``<folder>/<name>.yaml`` of ``components`` (in their order) and
    ``fluid``; its path."""
    path = folder / f'{name}.yaml'
    path.write_text(yaml.safe_dump({'name': name, 'fluid': fluid, 'components': components},
                                   sort_keys=False))
    return path


@pytest.fixture
def short_connect(monkeypatch):
    """An address nothing answers is refused once the Dask connect timeout runs out: the
    refusal is what the tests that take this judge, so a short timeout spares them its 5 s a
    try."""
    from hydropump_ctrl import batch
    monkeypatch.setattr(batch, 'CONNECT_TIMEOUT', 0.5)
