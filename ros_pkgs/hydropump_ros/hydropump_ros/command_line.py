"""The one place a node's command line is built, as ``ros2 run`` would start it: the
executable the ament index names, then ``--ros-args`` with the namespace, the log level,
parameter files and parameters (``-p name:=value``, values written as ROS parses them).
The graph of one pump (simulator, controller, recorder and the optional foxglove node) is
described once, by :func:`graph_nodes` from the launch arguments: ``closed_loop.launch.py``
turns it into launch_ros's ``Node`` actions, ``hydropump-graph`` into command lines, and the
orchestration of the demo and ``hydropump record`` starts its nodes through
:func:`node_command`.

Light at import (no rclpy): ``hydropump-graph --help`` must not pay for ROS.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
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


@dataclass(frozen=True)
class NodeSpec:
    """One node of the graph: its name (and executable), its parameter files and its
    parameters, in the order ROS applies them (files first)."""

    name: str
    params: dict = field(default_factory=dict)
    params_files: tuple = ()
    lifecycle: bool = False

    def command(self, namespace: str = '', log_level: str | None = None) -> list[str]:
        """Its command line, as ``ros2 run`` starts it."""
        return node_command(self.name, self.params, namespace=namespace, log_level=log_level,
                            params_files=self.params_files)


def graph_nodes(*, params_file: str | Path, sensor_profile: str | Path | None = None,
                circuit_file: str | None = None, scenario_file: str | None = None,
                controller_params: str | None = None, use_sim_time: bool = False,
                lock_step: bool = False, real_time_factor: float = 1.0,
                start_paused: bool = False, autostart: bool = True, record: bool = True,
                topics: Sequence[str] = (), bag: str | None = None,
                compression: str = 'zstd', foxglove_port: int | None = None
                ) -> list[NodeSpec]:
    """The nodes of one pump's graph from the launch arguments (``None`` or empty: the
    node's own default)."""
    sim = {'use_sim_time': use_sim_time, 'lock_step': lock_step,
           'real_time_factor': float(real_time_factor), 'start_paused': start_paused}
    if scenario_file:
        sim['scenario_file'] = str(scenario_file)
    if circuit_file:
        sim['circuit_file'] = str(circuit_file)
    # Lock-step: a simulation held back by a slow peer is no fault of the measurements.
    ctrl = {'use_sim_time': use_sim_time, 'autostart': autostart,
            'watchdog.simulation_time': lock_step}
    if controller_params:
        ctrl['config_file'] = str(controller_params)
    files = (str(params_file),) + ((str(sensor_profile),) if sensor_profile else ())
    nodes = [NodeSpec('simulator', sim, files),
             NodeSpec('controller', ctrl, lifecycle=True)]
    if record:
        rec = {'use_sim_time': use_sim_time, 'compression': compression}
        if bag:
            rec['output'] = str(bag)
        topics = [t.strip() for t in topics if t.strip()]
        if not topics and circuit_file:
            # The suite's topics and what the circuit adds (ls_pressure, loads/<name>/...).
            from hydropump_sim.measure import recorded_topics
            topics = recorded_topics(circuit_file)
        if topics:
            rec['topics'] = list(topics)
        nodes.append(NodeSpec('recorder', rec))
    if foxglove_port is not None:
        # Its default topics, and discovery, take what a circuit adds as it appears.
        nodes.append(NodeSpec('foxglove', {'use_sim_time': use_sim_time,
                                           'port': int(foxglove_port)}))
    return nodes
