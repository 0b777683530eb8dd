"""Fixtures for node tests: a reserved ROS domain, localhost discovery, one rclpy context."""

import os
import random

import pytest

os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'


def _suite_dds_profile():
    # The test process publishes as a node of the suite would (a stand-in controller's
    # commands): with the nodes' writer settings, config/fastdds.xml. Under Fast DDS's own
    # (a 3 s heartbeat) a sample a starved recorder missed came back seconds late, after the
    # recorder had taken the silent topic as ended, and the bag lacked the tail.
    from hydropump_ros.entry import dds_profile
    dds_profile()


_suite_dds_profile()


@pytest.fixture(scope='session')
def ros_domain():
    """A ROS_DOMAIN_ID reserved for this test session (no cross-talk with other runs)."""
    from domain_coordinator import domain_id
    start = random.randrange(100)

    def selector(state=[start]):  # noqa: B006 - the counter lives across calls
        state[0] += 1
        return state[0] % 100 + 1

    with domain_id(selector) as did:
        os.environ['ROS_DOMAIN_ID'] = str(did)
        yield did


@pytest.fixture(scope='session')
def rclpy_context(ros_domain):
    import rclpy
    rclpy.init()
    yield
    rclpy.try_shutdown()


@pytest.fixture
def test_node(rclpy_context):
    from rclpy.node import Node
    node = Node(f'test_{os.getpid()}_{random.randrange(10**6)}')
    yield node
    node.destroy_node()


@pytest.fixture
def nodes(tmp_path, ros_domain):
    """Start node processes with ``nodes.start(name, *ros_args)``; all are ended by PID."""
    from .rosutil import NodeProcess
    started = []

    class Starter:
        # Extra arguments per node name, for a test that reuses another test's run.
        extra: dict = {}

        def start(self, name, *ros_args):
            p = NodeProcess(name, list(ros_args) + self.extra.get(name, []), tmp_path)
            started.append(p)
            return p

    yield Starter()
    for p in started:
        p.stop()
