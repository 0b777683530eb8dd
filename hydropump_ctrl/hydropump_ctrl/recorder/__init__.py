"""The recorder without ROS: its configuration, the ordering of messages, the bag writer.

- :class:`RecorderConfig`: the recorder node's parameters (one schema, defaults included);
- :class:`~.sequencer.Sequencer`: log times by the rule of time and the per-topic watermark
  that writes a bag in log-time order, also when the recorder lags;
- :class:`~.bag.BagWriter`: rosbag2 bags as rosbag2 Jazzy writes them (MCAP);
- :class:`~.session.Recorder`: the bags of a recording node and their rules (time base,
  new bags on a new simulator, stop).

The node (``hydropump_ros.recorder_node``) only takes the messages and the graph's QoS.
"""

from __future__ import annotations

from dataclasses import dataclass

from hydropump_sim.schema import spec

from .bag import BagError, BagWriter, message_definition, qos_profile, unique_path
from .sequencer import Record, Sequencer
from .session import header_stamp, Recorder, Session

__all__ = ['BagError', 'BagWriter', 'DEFAULT_TOPICS', 'Record', 'Recorder', 'RecorderConfig',
           'Sequencer', 'Session', 'SUITE_TYPES', 'header_stamp', 'message_definition',
           'qos_profile', 'unique_path']

# The suite's topics and their types; other topics are looked up in the ROS graph.
SUITE_TYPES = {
    'solenoid_current_cmd': 'std_msgs/msg/Float64',
    'solenoid_current': 'std_msgs/msg/Float64',
    'pump_flow': 'std_msgs/msg/Float64',
    'line_flow': 'std_msgs/msg/Float64',
    'load_flow': 'std_msgs/msg/Float64',
    'actuator_pressure': 'sensor_msgs/msg/FluidPressure',
    'line_pressure': 'sensor_msgs/msg/FluidPressure',
    'load_pressure': 'sensor_msgs/msg/FluidPressure',
    'joint_states': 'sensor_msgs/msg/JointState',
    'controller/state': 'sensor_msgs/msg/JointState',
    '/diagnostics': 'diagnostic_msgs/msg/DiagnosticArray',
    '/clock': 'rosgraph_msgs/msg/Clock',
}
DEFAULT_TOPICS = ['solenoid_current_cmd', 'solenoid_current', 'pump_flow', 'line_flow',
                  'load_flow', 'actuator_pressure', 'line_pressure', 'load_pressure',
                  'joint_states', 'controller/state']


@dataclass(frozen=True)
class RecorderConfig:
    """The recorder node's parameters."""

    topics: list = spec('-', 'topics to record (relative names resolve in the namespace)',
                        default=DEFAULT_TOPICS)
    output: str = spec('path', 'bag folder; empty = bags/recorder_<time> under the working '
                       'directory; an existing one is never overwritten (a suffix _1, _2, '
                       '... is added)', default='', live=True)
    autostart: bool = spec('-', 'open a bag and record at start-up', default=True)
    compression: str = spec('-', 'MCAP chunk compression, as rosbag2 presets do',
                            choices=('zstd', 'none'), default='zstd')
    flush_period: float = spec('s', 'close and flush an MCAP chunk at every multiple of this '
                               'in log time: what a hard kill can cost', 0.01, 10.0,
                               default=0.25)
    idle_timeout: float = spec('s', 'steady-clock silence after which a topic no longer holds '
                               'the others back', 0.05, 60.0, default=1.0)
    clock_wait: float = spec('s', 'how long after its first message a bag with no /clock '
                             'publisher in the graph waits before it records in wall time '
                             '(longer than a discovery that missed its first announcements)',
                             0.0, 60.0, default=4.0)
    take_batch: int = spec('-', 'messages taken per topic per pass of the take loop', 1,
                           100000, default=200)
    stop_time: float = spec('s', 'simulation time a ~/stop ends the bag at, once every topic '
                            'has delivered up to it (an orchestrator that paused the simulator '
                            'there gets the same bag however loaded the machine); 0 = the '
                            'latest /clock', 0.0, 1.0e6, default=0.0, live=True)
