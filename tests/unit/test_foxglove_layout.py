"""Foxglove layouts for a pump in a namespace and for a circuit: every plot names the
graph's own topics, the shipped circuit layout is the one generated from its circuit file,
and a user's file is never replaced."""

import json
from pathlib import Path

import pytest
import yaml

from hydropump_ctrl.foxglove import BASE_LAYOUT, layout, write_layout, WRITTEN_BY
from hydropump_sim.circuit import load_circuit
from hydropump_sim.measure import model_topics

from ..conftest import ROOT

FIG1 = ROOT / 'config' / 'circuits' / 'fig1.yaml'


def _paths(lay):
    return [p['value'] for c in lay['configById'].values() for p in c.get('paths', [])]


def _panels_in(tree):
    if isinstance(tree, str):
        return [tree]
    return _panels_in(tree['first']) + _panels_in(tree['second'])


def test_a_namespaced_circuit_layout_plots_every_load_under_the_namespace(tmp_path):
    base = json.loads(BASE_LAYOUT.read_text())
    path = write_layout(tmp_path / 'view.json', 'pump1', str(FIG1))
    lay = json.loads(path.read_text())
    paths = _paths(lay)
    # The pump's plots, moved under the namespace, every one.
    assert all(p.startswith('/pump1/') for p in paths)
    assert {'/pump1' + p for p in _paths(base)} <= set(paths)
    # The circuit's sections, as the circuit file names them (read here as plain YAML):
    # each one's flow, pressures and position; the load-sensing pressure.
    doc = yaml.safe_load(FIG1.read_text())
    sections = [n for n, c in doc['components'].items() if c['type'] == 'section']
    assert len(sections) == 3
    for name in sections:
        assert f'/pump1/loads/{name}/flow.data' in paths
        assert f'/pump1/loads/{name}/pressure.fluid_pressure' in paths
    assert '/pump1/ls_pressure.fluid_pressure' in paths
    # Every panel placed once in the layout tree; health stays global.
    assert sorted(_panels_in(lay['layout'])) == sorted(lay['configById'])
    assert lay['configById']['DiagnosticSummary!diagnostics']['topicToRender'] == \
        '/diagnostics'
    assert lay['globalVariables'] == {'written_by': WRITTEN_BY, 'namespace': '/pump1'}


def test_the_shipped_circuit_layout_is_the_one_its_circuit_gives():
    shipped = json.loads((ROOT / 'config' / 'foxglove' / 'fig1.json').read_text())
    want = layout(json.loads(BASE_LAYOUT.read_text()), '',
                  model_topics(load_circuit(str(FIG1), compile=False))[0])
    assert shipped == want
    assert len(_paths(shipped)) > len(_paths(json.loads(BASE_LAYOUT.read_text())))


def test_a_users_file_is_never_replaced_and_its_own_is(tmp_path):
    mine = tmp_path / 'foxglove_layout.json'
    mine.write_text('{"my": "layout"}')
    with pytest.raises(FileExistsError, match='not a layout hydropump wrote'):
        write_layout(mine, 'pump1')
    assert mine.read_text() == '{"my": "layout"}'
    ours = write_layout(tmp_path / 'ours.json', 'pump1')
    write_layout(ours, 'pump2')  # its own: replaced
    assert all(p.startswith('/pump2/') for p in _paths(json.loads(ours.read_text())))
    assert not list(Path(tmp_path).glob('*.tmp'))
