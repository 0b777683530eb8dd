"""The one place a node's command line is built, as ``ros2 run`` would start it: the
executable the ament index names, then ``--ros-args`` with the namespace, the log level,
parameter files and parameters (``-p name:=value``, values written as ROS parses them).
``hydropump-graph`` and the orchestration of the demo and ``hydropump record`` start their
nodes through it; the launch files describe the same nodes with launch_ros's ``Node``.

Light at import (no rclpy): ``hydropump-graph --help`` must not pay for ROS.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from pathlib import Path

#: The suite's three nodes.
NODES = ('simulator', 'controller', 'recorder')


def executable(name: str) -> str:
    """``<prefix>/lib/hydropump_ros/<name>``, as ``ros2 run`` finds it."""
    from ament_index_python.packages import get_package_prefix
    return str(Path(get_package_prefix('hydropump_ros')) / 'lib' / 'hydropump_ros' / name)


def ros_value(v) -> str:
    """A parameter value as the ROS command line takes it (``true``, ``0.5``, ``[a, b]``)."""
    if isinstance(v, bool):
        return 'true' if v else 'false'
    if isinstance(v, float):
        return repr(v)
    if isinstance(v, (list, tuple)):
        return '[' + ', '.join(str(x) for x in v) + ']'
    return str(v)


def param_args(values: Mapping[str, object]) -> list[str]:
    """``-p name:=value`` for each parameter."""
    out = []
    for k, v in values.items():
        out += ['-p', f'{k}:={ros_value(v)}']
    return out


def node_command(name: str, params: Mapping[str, object] | None = None, *,
                 namespace: str = '', log_level: str | None = None,
                 params_files: Iterable[str | Path] = ()) -> list[str]:
    """The command line of node ``name``."""
    args = []
    if log_level:
        args += ['--log-level', log_level]
    if namespace.strip('/'):
        args += ['-r', f'__ns:=/{namespace.strip("/")}']
    for f in params_files:
        args += ['--params-file', str(f)]
    return [executable(name), '--ros-args', *args, *param_args(params or {})]
