"""The circuit of the paper's Fig. 1 through the nodes: the pump feeding a relief valve, a
priority steering load and two loads on demand, under electronic load sensing (margin mode
against the highest load).

    ros2 launch hydropump_bringup fig1.launch.py namespace:=pump1 bag:=/tmp/fig1
    ros2 topic pub --once /pump1/loads/boom/command std_msgs/msg/Float64 "{data: 0.8}"

Every argument of closed_loop.launch.py is accepted; this file only changes the defaults:
``circuit_file`` config/circuits/fig1.yaml, ``controller_params`` config/controller_fig1.yaml
(``hydropump design --circuit``: EMC in margin mode on the circuit's line), and the recorder
records the circuit's topics too (``ls_pressure``, ``loads/<name>/...``).
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import IncludeLaunchDescription
from launch.launch_description_sources import PythonLaunchDescriptionSource
from launch.substitutions import LaunchConfiguration


def generate_launch_description():
    share = get_package_share_directory('hydropump_bringup')
    config = os.path.join(share, 'config')
    base = os.path.join(share, 'launch', 'closed_loop.launch.py')
    defaults = {'circuit_file': os.path.join(config, 'circuits', 'fig1.yaml'),
                'controller_params': os.path.join(config, 'controller_fig1.yaml')}
    # Each default stands unless the command line gives the argument.
    args = {k: LaunchConfiguration(k, default=v) for k, v in defaults.items()}
    return LaunchDescription([IncludeLaunchDescription(PythonLaunchDescriptionSource(base),
                                                       launch_arguments=args.items())])
