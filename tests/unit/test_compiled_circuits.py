"""How a circuit compiles and steps: a source that does not grow with its components, a
rejected step retried on the same Jacobian, section IV's static forms of composite parts."""

import os
import re
import subprocess
import sys

import numpy as np
import yaml

from hydropump_sim import integrator as ig
from hydropump_sim.circuit import load_circuit
from hydropump_sim.steady import equilibrium

from ..conftest import ROOT

CIRCUITS = ROOT / 'config' / 'circuits'
TABLE = re.compile(r'^T\d+ = np\.array\(')


def sections(tmp_path, n):
    """three_loads with ``n`` load sections, not compiled."""
    doc = yaml.safe_load((CIRCUITS / 'three_loads.yaml').read_text())
    comps = {k: v for k, v in doc['components'].items() if not k.startswith('load')}
    for k in range(n):
        comps[f's{k}'] = dict(doc['components']['load1'],
                              ports={'supply': 'supply', 'tank': 'tank', 'load': f's{k}_a',
                                     'sense': f's{k}_ls'})
    comps['ls']['ports']['in'] = [f's{k}_ls' for k in range(n)]
    doc.update(components=comps, plant=str(ROOT / 'config' / 'pump.yaml'))
    path = tmp_path / f'sections_{n}.yaml'
    path.write_text(yaml.safe_dump(doc))
    return load_circuit(path, compile=False)


def test_the_generated_source_does_not_grow_with_the_number_of_components(tmp_path):
    """What numba compiles is one loop per component type over index tables: four times the
    sections, the same code (only the tables' data grows), so the compile time and memory
    do not grow with the components (one call per component took 280 s at 40 sections)."""
    small, big = sections(tmp_path, 3), sections(tmp_path, 12)
    assert big.n_states > 3 * small.n_states - 30
    # The same code but for the tables and the sizes in it (y[0:15] -> y[0:51]).
    code = [[re.sub(r'\d+', 'N', line) for line in c.code.splitlines() if not TABLE.match(line)]
            for c in (small, big)]
    assert code[0] == code[1]
    kinds = {type(pt.comp).__module__ for pt in big.parts}
    calls = [line for line in code[1] if re.match(r'\s+k_N\(', line)]
    assert len(calls) == len(kinds)
    # The tables hold indices only: every one of the 12 sections' kernels is called.
    assert sum(line.count('[') for line in big.code.splitlines() if TABLE.match(line)) > \
        sum(line.count('[') for line in small.code.splitlines() if TABLE.match(line))


def test_a_rejected_step_is_retried_on_the_same_jacobian_exactly():
    """After a rejection the stepper keeps the Jacobian (the point has not moved): the
    retried step is the one a fresh Jacobian gives, to the last bit."""
    c = load_circuit(CIRCUITS / 'fig1.yaml')
    u = c.u0.copy()
    u[c.input_index('boom.command')] = 1.0       # a step from rest: a stiff transient
    x = equilibrium(c, c.u0).x
    m = c.stepper_model()
    X, P = x[None].copy(), c.p[None]
    no_dense = np.empty((0, 2, c.n_states))
    ws = ig.workspace(c.n_states, c.n_signals)
    out = np.empty_like(X)
    assert ig.rodas_step(m, 0.0, X, u, P, 0.5, 1e-5, out, False, ws, no_dense) > 1.0
    ig.rodas_step(m, 0.0, X, u, P, 1e-5, 1e-5, out, False, ws, no_dense, True)
    fresh = np.empty_like(X)
    ig.rodas_step(m, 0.0, X, u, P, 1e-5, 1e-5, fresh, False,
                  ig.workspace(c.n_states, c.n_signals), no_dense)
    assert np.array_equal(out, fresh)
    assert not np.array_equal(out, X)


def test_every_part_of_a_composite_can_be_made_static():
    """Section IV's static form of a composite's parts is set through the group its values
    come from (a side's compensator, the brake valves, cross-port reliefs): the excavator
    made static loses exactly the states each part's static form does without."""
    ex = load_circuit(CIRCUITS / 'excavator.yaml')
    gone = ex.reducible()
    assert {'boom.comp_b', 'swing.relief_ab', 'arm.brake_b'} <= set(gone)
    simple = ex.made_static(list(gone))
    removed = {s for states in gone.values() for s in states}
    assert set(simple.states) == set(ex.states) - removed


def test_a_circuits_first_compile_says_so_and_the_next_process_loads_it(tmp_path):
    """A structure compiled for the first time says so on stderr, with how long it took;
    the next process loads numba's cached code and is silent."""
    code = ('from hydropump_sim.circuit import load_circuit\n'
            f'load_circuit({str(CIRCUITS / "three_loads.yaml")!r}).evaluate_c\n')
    env = dict(os.environ, HYDROPUMP_CACHE=str(tmp_path / 'cache'))
    first, again = (subprocess.run([sys.executable, '-c', code], capture_output=True,
                                   text=True, env=env, timeout=600) for _ in range(2))
    assert first.returncode == 0 and again.returncode == 0, first.stderr + again.stderr
    lines = first.stderr.splitlines()
    assert lines[0].startswith("compiling the circuit's equations (once per structure")
    assert re.fullmatch(r'compiled in \d+\.\d s', lines[1])
    assert again.stderr == ''
