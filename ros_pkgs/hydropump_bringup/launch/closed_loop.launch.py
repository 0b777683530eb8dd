"""Simulator, controller and recorder of one pump, in one namespace (and, with
``foxglove:=true``, the live view on ``ws://127.0.0.1:<foxglove_port>``).

    ros2 launch hydropump_bringup closed_loop.launch.py namespace:=pump1 \
        sensor_profile:=<share>/config/bench.yaml lock_step:=true bag:=/tmp/run1

The simulator owns simulation time (it publishes /clock): the controller and the recorder
follow it whatever use_sim_time says (docs/ros.md, "rules of time"); use_sim_time only changes
the ROS clock of the nodes. Several pumps share a ROS domain in namespaces of their own
(``namespace:=pump1``, ``namespace:=pump2``: each has its /<ns>/clock); two simulators in
one namespace are refused. Without ros2 launch, ``hydropump-graph`` starts the same graph
with the same arguments. Bags go to ``bag`` (an absolute path, or relative to the folder
ros2 launch runs in); empty: ``bags/recorder_<time>`` there. The recorder logs the absolute
path.
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import LifecycleNode, Node

# Launch arguments: (name, default, description). Empty paths mean the node's own default.
ARGUMENTS = [
    ('namespace', '', 'namespace of the suite, e.g. pump1'),
    ('use_sim_time', 'false', 'ROS clock of the nodes on /clock (the suite follows /clock '
                              'anyway)'),
    ('params_file', '{config}/pump.yaml', 'plant parameters (ROS 2 params file)'),
    ('circuit_file', '', "circuit the pump feeds (config/circuits/*.yaml); empty = the paper's "
                         'load (config/circuits/paper.yaml)'),
    ('sensor_profile', '{config}/sensors.yaml', 'sensor profile; config/bench.yaml is the '
                                                'test bench'),
    ('controller_params', '{config}/controller.yaml', 'controller parameters (from '
                                                      'hydropump design)'),
    ('scenario_file', '', 'load pressure, aperture and shaft speed scheduled in simulation '
                          'time'),
    ('lock_step', 'false', 'simulator advances one control period per command'),
    ('real_time_factor', '1.0', 'simulator pacing; 0 = as fast as possible'),
    ('start_paused', 'false', 'simulator waits for ~/pause false before t = 0'),
    ('autostart', 'true', 'controller configures and activates at start-up'),
    ('log_level', 'info', 'log level of every node (debug, info, warn, error)'),
    ('record', 'true', 'start the recorder'),
    ('topics', '', "topics the recorder records, comma-separated; empty = the suite's "
                   'measurement and command topics'),
    ('bag', '', 'bag folder of the recorder; empty = bags/recorder_<time> in the working '
                'directory'),
    ('compression', 'zstd', 'MCAP chunk compression of the bag: zstd or none'),
    ('foxglove', 'false', 'start the foxglove node: the topics live over the Foxglove '
                          'WebSocket protocol (config/foxglove/hydropump.json is a layout)'),
    ('foxglove_port', '8765', 'TCP port of the foxglove node (on 127.0.0.1)'),
]


def _nodes(context):
    """The graph's nodes (``hydropump_ros.command_line.graph_nodes``, the one description
    ``hydropump-graph`` starts too) from the launch arguments' values; empty ones are left
    to the nodes' own defaults."""
    from hydropump_ros.command_line import graph_nodes
    a = {name: context.perform_substitution(LaunchConfiguration(name))
         for name, _, _ in ARGUMENTS}

    def flag(name):
        return a[name].strip().lower() == 'true'

    nodes = graph_nodes(
        params_file=a['params_file'], sensor_profile=a['sensor_profile'] or None,
        circuit_file=a['circuit_file'] or None, scenario_file=a['scenario_file'] or None,
        controller_params=a['controller_params'] or None,
        use_sim_time=flag('use_sim_time'), lock_step=flag('lock_step'),
        real_time_factor=float(a['real_time_factor']), start_paused=flag('start_paused'),
        autostart=flag('autostart'), record=flag('record'), topics=a['topics'].split(','),
        bag=a['bag'] or None, compression=a['compression'],
        foxglove_port=int(a['foxglove_port']) if flag('foxglove') else None)
    return [(LifecycleNode if n.lifecycle else Node)(
        package='hydropump_ros', executable=n.name, name=n.name, namespace=a['namespace'],
        output='screen', ros_arguments=['--log-level', a['log_level']],
        parameters=[*n.params_files, n.params]) for n in nodes]


def generate_launch_description():
    config = os.path.join(get_package_share_directory('hydropump_bringup'), 'config')
    args = [DeclareLaunchArgument(name, default_value=default.format(config=config),
                                  description=desc) for name, default, desc in ARGUMENTS]
    return LaunchDescription(args + [OpaqueFunction(function=_nodes)])
