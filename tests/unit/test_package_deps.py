"""The package.xml files list what the packages import, with rosdep keys, so that `rosdep
install --from-paths hydropump_sim hydropump_ctrl ros_pkgs` installs what the code needs on a
ROS machine; every key the public rosdep database lacks is in rosdep/hydropump.yaml, pinned
as requirements.txt pins it."""

import ast
from pathlib import Path
import re
import sys
import xml.etree.ElementTree as ET

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[2]
PACKAGES = {'hydropump_sim': ROOT / 'hydropump_sim',
            'hydropump_ctrl': ROOT / 'hydropump_ctrl',
            'hydropump_ros': ROOT / 'ros_pkgs' / 'hydropump_ros'}
# A third-party module -> its rosdep key and its PyPI distribution (None: a ROS package,
# whose key is its own name). Keys ending in -pip that rosdep lacks live in our YAML.
THIRD_PARTY = {
    'numpy': ('python3-numpy', 'numpy'), 'scipy': ('python3-scipy', 'scipy'),
    'numba': ('python3-numba', 'numba'), 'yaml': ('python3-yaml', 'PyYAML'),
    'matplotlib': ('python3-matplotlib', 'matplotlib'), 'tqdm': ('python3-tqdm', 'tqdm'),
    'PIL': ('python3-pil', 'pillow'),
    'control': ('python3-control-pip', 'control'),
    'rosbags': ('python3-rosbags-pip', 'rosbags'),
    'mcap': ('python3-mcap-pip', 'mcap'),
    'threadpoolctl': ('python3-threadpoolctl-pip', 'threadpoolctl'),
    'foxglove': ('python3-foxglove-sdk-pip', 'foxglove-sdk'),
    'dask': ('python3-dask-distributed-pip', 'dask'),
    'pyarrow': ('python3-pyarrow-pip', 'pyarrow'),
    'SALib': ('python3-salib-pip', 'SALib'),
    'fmpy': ('python3-fmpy-pip', 'fmpy'),
    'pythonfmu': ('python3-pythonfmu-pip', 'pythonfmu'),
    'pythonfmu3': ('python3-pythonfmu3-pip', 'pythonfmu3'),
}
# -pip keys the public rosdep database has (rosdep/python.yaml of ros/rosdistro).
UPSTREAM_PIP = {'python3-rosbags-pip'}
ROS_PACKAGES = {'rclpy', 'std_msgs', 'std_srvs', 'sensor_msgs', 'diagnostic_msgs',
                'rosgraph_msgs', 'lifecycle_msgs', 'builtin_interfaces', 'rcl_interfaces',
                'ament_index_python', 'domain_coordinator'}


def imports_of(folder: Path, own: str) -> set[str]:
    """Top-level modules the package's sources import, the standard library's and its own
    left out."""
    out = set()
    for path in (folder / own).rglob('*.py'):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                out |= {a.name.split('.')[0] for a in node.names}
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                out.add(node.module.split('.')[0])
    return {m for m in out if m not in sys.stdlib_module_names and m != own}


def depends(folder: Path, tag: str = 'exec_depend') -> set[str]:
    return {e.text.strip() for e in ET.parse(folder / 'package.xml').getroot().iter(tag)}


def key_of(module: str) -> str:
    if module in PACKAGES or module in ROS_PACKAGES:
        return module
    assert module in THIRD_PARTY, f'{module}: no rosdep key known; add it here and to ' \
                                  'package.xml'
    return THIRD_PARTY[module][0]


@pytest.mark.parametrize('name', list(PACKAGES))
def test_package_xml_lists_exactly_what_the_package_imports(name):
    folder = PACKAGES[name]
    wanted = {key_of(m) for m in imports_of(folder, name)}
    listed = depends(folder)
    assert wanted - listed == set(), f'{name}/package.xml lacks these'
    assert listed - wanted == set(), f'{name}/package.xml lists what no module imports'


def test_every_private_key_is_defined_and_pinned_as_requirements_pins_it():
    ours = yaml.safe_load((ROOT / 'rosdep' / 'hydropump.yaml').read_text())
    pins = dict(re.findall(r'^([A-Za-z0-9_.\-\[\]]+)==(\S+)$',
                           (ROOT / 'requirements.txt').read_text(), re.M))
    used = set()
    for folder in PACKAGES.values():
        used |= depends(folder) | depends(folder, 'test_depend')
    for key in sorted(k for k in used if k.endswith('-pip')):
        if key in UPSTREAM_PIP:
            continue
        assert key in ours, f'{key}: not in rosdep/hydropump.yaml'
        for os_name in ('debian', 'ubuntu'):
            for spec in ours[key][os_name]['pip']['packages']:
                dist, version = spec.split('==')
                assert pins.get(dist) == version, f'{key}: {spec} against requirements.txt'
    # Every PyPI distribution a package imports is pinned.
    for module, (_key, dist) in THIRD_PARTY.items():
        assert dist in pins, f'{dist} ({module}) is not pinned in requirements.txt'
