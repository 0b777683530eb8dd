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

from hydropump_sim.measure import FLOAT64, JOINT_STATE, suite_topics
from hydropump_sim.measure import SIGNALS as MEASURED
from hydropump_sim.schema import closest_name, spec

from ..bag import BagError, BagWriteError, BagWriter, message_definition, qos_profile, unique_path
from .sequencer import Record, Sequencer
from .session import DRAIN_TIMEOUT, header_stamp, Recorder, Session

__all__ = ['BagError', 'BagWriteError', 'BagWriter', 'DEFAULT_TOPICS', 'Record', 'Recorder',
           'RecorderConfig', 'Sequencer', 'Session', 'SUITE_TYPES', 'header_stamp',
           'message_definition', 'qos_profile', 'unique_path', 'unpublished_note']

# The suite's topics and their types (the plant's from the one signal table); other topics
# are looked up in the ROS graph.
_PLANT_TOPICS = {i.topic: i.msgtype for i in MEASURED.values()}
SUITE_TYPES = {
    'solenoid_current_cmd': FLOAT64,
    **_PLANT_TOPICS,
    'controller/state': JOINT_STATE,
    '/diagnostics': 'diagnostic_msgs/msg/DiagnosticArray',
    '/clock': 'rosgraph_msgs/msg/Clock',
    'events': 'diagnostic_msgs/msg/DiagnosticArray',
}
DEFAULT_TOPICS = suite_topics()


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
    drain_timeout: float = spec('s', 'at a stop (~/stop, SIGINT, SIGTERM), how long the bag '
                                'waits at most for what was published up to the stop and is '
                                'still on its way; what it has not got then is counted as lost',
                                0.1, 60.0, default=DRAIN_TIMEOUT)


def unpublished_note(topic: str, known, grace: float) -> str:
    """What to say of a recorded topic that no publisher offered within ``grace`` s: most
    often a typo, so the nearest of ``known`` (the suite's topics and the graph's, resolved)
    is named: ``no publisher on /lien_pressure after 5 s (did you mean /line_pressure?)``."""
    close = closest_name(topic, [k for k in known if k != topic])
    hint = f' (did you mean {close}?)' if close else ''
    return f'no publisher on {topic} after {grace:g} s{hint}'
