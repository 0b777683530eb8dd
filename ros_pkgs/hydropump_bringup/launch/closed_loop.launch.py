"""Simulator, controller and recorder of one pump, in one namespace.

    ros2 launch hydropump_bringup closed_loop.launch.py namespace:=pump1 \
        sensor_profile:=<share>/config/bench.yaml lock_step:=true

The simulator owns simulation time (it publishes /clock); the controller and the recorder run
on it when use_sim_time is true. The controller is a lifecycle node; autostart configures and
activates it. Without ros2 launch, ``hydropump-graph`` starts the same graph.
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.conditions import IfCondition
from launch.substitutions import LaunchConfiguration, PythonExpression
from launch_ros.actions import LifecycleNode, Node


def generate_launch_description():
    config = os.path.join(get_package_share_directory('hydropump_bringup'), 'config')
    namespace = LaunchConfiguration('namespace')
    use_sim_time = LaunchConfiguration('use_sim_time')
    params_file = LaunchConfiguration('params_file')
    sensor_profile = LaunchConfiguration('sensor_profile')
    controller_params = LaunchConfiguration('controller_params')
    sim_time = {'use_sim_time': PythonExpression(["'", use_sim_time, "' == 'true'"])}

    args = [
        DeclareLaunchArgument('namespace', default_value='',
                              description='namespace of the suite, e.g. pump1'),
        DeclareLaunchArgument('use_sim_time', default_value='true',
                              description='controller and recorder on the simulator clock'),
        DeclareLaunchArgument('params_file', default_value=os.path.join(config, 'pump.yaml'),
                              description='plant parameters (ROS 2 params file)'),
        DeclareLaunchArgument('sensor_profile', default_value=os.path.join(config,
                                                                           'sensors.yaml'),
                              description='sensor profile; config/bench.yaml is the test bench'),
        DeclareLaunchArgument('controller_params',
                              default_value=os.path.join(config, 'controller.yaml'),
                              description='controller parameters'),
        DeclareLaunchArgument('lock_step', default_value='false',
                              description='simulator advances one control period per command'),
        DeclareLaunchArgument('real_time_factor', default_value='1.0',
                              description='simulator pacing; 0 = as fast as possible'),
        DeclareLaunchArgument('bag', default_value='', description='recorder output directory'),
        DeclareLaunchArgument('record', default_value='true', description='start the recorder'),
    ]
    simulator = Node(
        package='hydropump_ros', executable='simulator', name='simulator',
        namespace=namespace, output='screen',
        parameters=[params_file, sensor_profile,
                    {'lock_step': PythonExpression(["'", LaunchConfiguration('lock_step'),
                                                    "' == 'true'"]),
                     'real_time_factor': LaunchConfiguration('real_time_factor')}])
    controller = LifecycleNode(
        package='hydropump_ros', executable='controller', name='controller',
        namespace=namespace, output='screen',
        parameters=[controller_params, sim_time, {'autostart': True}])
    recorder = Node(
        package='hydropump_ros', executable='recorder', name='recorder',
        namespace=namespace, output='screen',
        parameters=[sim_time, {'output': LaunchConfiguration('bag')}],
        condition=IfCondition(LaunchConfiguration('record')))
    return LaunchDescription(args + [simulator, controller, recorder])
