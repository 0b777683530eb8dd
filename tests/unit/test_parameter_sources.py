"""One source of truth for every parameter: the schemas. The docs' tables are generated from
them, the config files hold only names the schemas know, with valid values."""

from pathlib import Path
import subprocess
import sys

import pytest

from hydropump_ctrl.control.schema import ControllerConfig
from hydropump_ctrl.control.supervisor import ControllerNodeConfig
from hydropump_ctrl.recorder import RecorderConfig
from hydropump_sim.params import Params
from hydropump_sim.runner import SimulatorConfig
from hydropump_sim.schema import check_all, defaults_of, read_params_file, spec_map
from hydropump_sim.sensors import SensorConfig

ROOT = Path(__file__).resolve().parents[2]


def test_the_parameter_tables_are_generated_from_the_schemas():
    proc = subprocess.run([sys.executable, str(ROOT / 'docs' / 'generate_tables.py'),
                           '--check'], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    readme = (ROOT / 'docs' / 'ros.md').read_text()
    for name in ('simulator', 'controller', 'recorder'):
        assert f'<!-- BEGIN params:{name} -->' in readme, name


@pytest.mark.parametrize('cls, node', [(SimulatorConfig, 'simulator'),
                                       (ControllerNodeConfig, 'controller'),
                                       (RecorderConfig, 'recorder')])
def test_the_node_parameter_tables_show_the_schema_defaults(cls, node):
    from hydropump_sim.schema import default_text
    readme = (ROOT / 'docs' / 'ros.md').read_text()
    block = readme.split(f'<!-- BEGIN params:{node} -->')[1].split('<!-- END')[0]
    rows = {line.split('|')[1].strip().strip('`'): line.split('|')[2].strip()
            for line in block.strip().splitlines()[2:]}
    specs = spec_map(cls)
    assert set(rows) == set(specs)
    for name, s in specs.items():
        assert rows[name] == default_text(s), name


@pytest.mark.parametrize('file, cls', [('pump.yaml', Params), ('controller.yaml',
                                                               ControllerConfig)])
def test_config_files_hold_every_required_name_and_only_known_ones(file, cls):
    _, errors = check_all(cls, read_params_file(ROOT / 'config' / file))
    assert not errors


def test_the_bench_profile_is_sensor_parameters_and_plant_overrides():
    flat = read_params_file(ROOT / 'config' / 'bench.yaml')
    sensors = {k: v for k, v in flat.items() if k.startswith('sensors.')}
    plant = {k: v for k, v in flat.items() if not k.startswith('sensors.')}
    assert not check_all(SensorConfig, sensors)[1]
    unknown = [e for e in check_all(Params, plant)[1] if 'unknown' in e]
    assert not unknown and plant


def test_one_safe_current_default_per_node():
    """The simulator's safe current is derived from the plant (0 % displacement), not a
    literal; the controller's comes with its design (limits.safe_current)."""
    assert defaults_of(SimulatorConfig)['safe_current'] == 0.0
    from hydropump_sim import Simulator
    from hydropump_sim.params import default_params_path, load_params
    from hydropump_sim.runner import Runner
    from hydropump_sim.schema import build
    params = load_params(default_params_path())
    runner = Runner(Simulator(params), build(SimulatorConfig, {}))
    assert runner.safe_current == pytest.approx(params.current_range[0])
