"""The launch file and ``hydropump-graph`` start one graph: the nodes the launch file describes
(read through stand-ins for ``launch`` and ``launch_ros``, which do not install here) carry
the same executables, parameter files and parameters as the command lines the graph command
builds from the same arguments."""

import importlib.util
import sys
import types

import pytest

from hydropump_ros import graph

from ..conftest import ROOT

LAUNCH = ROOT / 'ros_pkgs' / 'hydropump_bringup' / 'launch' / 'closed_loop.launch.py'
CONFIG = ROOT / 'config'


class _Action:
    def __init__(self, **kw):
        self.kw = kw


class Node(_Action):
    lifecycle = False


class LifecycleNode(_Action):
    lifecycle = True


class _Value:
    def __init__(self, name, default=None):
        self.name = name


@pytest.fixture
def launch_file(monkeypatch):
    """closed_loop.launch.py, imported over stand-ins of the launch API it uses."""
    stubs = {
        'launch': {'LaunchDescription': list},
        'launch.actions': {'DeclareLaunchArgument': _Action, 'OpaqueFunction': _Action},
        'launch.substitutions': {'LaunchConfiguration': _Value},
        'launch_ros': {},
        'launch_ros.actions': {'Node': Node, 'LifecycleNode': LifecycleNode},
    }
    for name, attrs in stubs.items():
        monkeypatch.setitem(sys.modules, name, types.SimpleNamespace(**attrs))
    spec = importlib.util.spec_from_file_location('closed_loop_launch', LAUNCH)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _launched(module, values):
    args = {name: default.format(config=CONFIG) for name, default, _ in module.ARGUMENTS}
    args.update(values)
    context = types.SimpleNamespace(perform_substitution=lambda v: args[v.name])
    return module._nodes(context)


def _parsed(command):
    """(executable, namespace, log level, params files, {name: value}) of a command line."""
    exe, rest = command[0].rsplit('/', 1)[-1], command[2:]
    files, params, ns, level = [], {}, '', None
    for flag, value in zip(rest[::2], rest[1::2]):
        if flag == '--params-file':
            files.append(value)
        elif flag == '-p':
            name, _, v = value.partition(':=')
            params[name] = v
        elif flag == '-r':
            ns = value.removeprefix('__ns:=/')
        elif flag == '--log-level':
            level = value
    return exe, ns, level, files, params


@pytest.mark.parametrize('launch_args, graph_args', [
    ({}, []),
    ({'namespace': 'pump1', 'lock_step': 'true', 'bag': '/tmp/run1', 'record': 'true',
      'log_level': 'debug', 'real_time_factor': '0.0', 'autostart': 'false',
      'compression': 'none', 'topics': 'a, b'},
     ['--namespace', 'pump1', '--lock-step', '--bag', '/tmp/run1', '--log-level', 'debug',
      '--real-time-factor', '0', '--no-autostart', '--compression', 'none', '--topics', 'a,b']),
    ({'circuit_file': str(CONFIG / 'circuits' / 'fig1.yaml'), 'foxglove': 'true',
      'foxglove_port': '8800', 'use_sim_time': 'true'},
     ['--circuit-file', str(CONFIG / 'circuits' / 'fig1.yaml'), '--foxglove', '8800',
      '--use-sim-time']),
])
def test_the_launch_file_and_the_graph_command_start_the_same_nodes(launch_file, launch_args,
                                                                     graph_args):
    from hydropump_ros.command_line import ros_value
    nodes = _launched(launch_file, launch_args)
    args = graph.build_parser().parse_args([
        '--params-file', str(CONFIG / 'pump.yaml'), '--sensor-profile',
        str(CONFIG / 'sensors.yaml'), '--controller-params', str(CONFIG / 'controller.yaml'),
        *graph_args])
    commands = graph.graph_commands(args)
    assert [n.kw['executable'] for n in nodes] == list(commands)
    for node in nodes:
        kw = node.kw
        exe, ns, level, files, params = _parsed(commands[kw['executable']])
        assert kw['package'] == 'hydropump_ros' and exe == kw['name'] == kw['executable']
        assert kw['namespace'] == ns and kw['ros_arguments'] == ['--log-level', level]
        assert node.lifecycle == (exe == 'controller')
        *given_files, given = kw['parameters']
        assert given_files == files
        assert {k: ros_value(v) for k, v in given.items()} == params
    # The arguments reach the nodes, not only both sides alike.
    by_name = {n.kw['name']: n.kw['parameters'][-1] for n in nodes}
    if launch_args.get('lock_step') == 'true':
        assert by_name['simulator']['lock_step'] is True
        assert by_name['controller']['watchdog.simulation_time'] is True
        assert by_name['recorder']['topics'] == ['a', 'b']
    if 'circuit_file' in launch_args:
        assert '/ls_pressure' in {t if t.startswith('/') else '/' + t
                                  for t in by_name['recorder']['topics']}
        assert by_name['foxglove']['port'] == 8800
