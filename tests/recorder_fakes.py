"""What the recorder's pure tests hand it in place of DDS: a graph whose topics are matched
with one publisher each, and CDR payloads of ``/clock`` and ``std_msgs/Float64``."""

import struct


class Graph:
    """The ROS side's answers for ``topics``, all ``std_msgs/msg/Float64``."""

    def __init__(self, topics=('/a',)):
        self.types = {t: 'std_msgs/msg/Float64' for t in topics}

    def matched(self):
        return list(self.types)

    def publishers(self, topic):
        return 1

    def offered_qos(self, topic):
        from hydropump_ctrl.recorder import qos_profile
        return [qos_profile()]


def clock_cdr(ns: int) -> bytes:
    """A ``rosgraph_msgs/Clock`` of ``ns`` nanoseconds, CDR little-endian."""
    return b'\x00\x01\x00\x00' + struct.pack('<iI', ns // 10 ** 9, ns % 10 ** 9)


def float_cdr(x: float = 1.0) -> bytes:
    """A ``std_msgs/Float64``, CDR little-endian."""
    return b'\x00\x01\x00\x00' + struct.pack('<d', x)
