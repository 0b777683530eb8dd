"""The physics and control packages never import ROS (architecture rule 1)."""

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
ROS_MODULES = ('rclpy', 'rosgraph_msgs', 'launch', 'launch_ros', 'ament_index_python')


def _is_ros(name: str) -> bool:
    top = name.split('.')[0]
    return top in ROS_MODULES or top.endswith('_msgs') or top.endswith('_srvs')


@pytest.mark.parametrize('pkg', ['hydropump_sim', 'hydropump_ctrl'])
def test_pure_package_has_no_ros_import(pkg):
    files = sorted((ROOT / pkg / pkg).rglob('*.py'))
    assert files
    bad = []
    for f in files:
        for node in ast.walk(ast.parse(f.read_text(), str(f))):
            names = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                names = [node.module]
            bad += [f'{f.relative_to(ROOT)}: {n}' for n in names if _is_ros(n)]
    assert not bad, bad


def test_scan_catches_a_ros_import():
    assert _is_ros('rclpy.node') and _is_ros('std_msgs.msg') and _is_ros('std_srvs.srv')
    assert not _is_ros('numpy') and not _is_ros('hydropump_sim.params')
