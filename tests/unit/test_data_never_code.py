"""Nothing in a data file is ever code, and no file can make a reader allocate without bound.

- Circuit files whose component, node or circuit names carry a newline, quotes, a closing
  docstring or ``__import__`` are refused with one line naming the entry, through the library
  and through ``hydropump circuit FILE``, and the payload (which would create a marker file)
  never runs; a valid circuit's generated source holds none of the file's strings.
- The compiled-circuit cache: a folder others may write into is skipped with a warning; an
  entry with the wrong mode (the module, numba's index) is removed and written anew, and a
  module whose source is not the generated one is never imported; as root, an entry owned by
  another user is ignored too.
- YAML: a document that expands through its aliases beyond a bound (an alias bomb), a
  recursive alias, a key given twice and an oversized file are refused with one line by
  every reader (params files, circuit files, ``--set`` values).
"""

import os
from pathlib import Path
import subprocess
import sys
import textwrap

import pytest
import yaml

from hydropump_sim.circuit import CircuitError, load_circuit
from hydropump_sim.params import load_params
from hydropump_sim.schema import MAX_YAML_BYTES, ParamError

from ..conftest import ROOT

CIRCUITS = ROOT / 'config' / 'circuits'
BIN = Path(sys.executable).parent


def payload(marker: Path) -> str:
    return f"__import__('pathlib').Path({str(marker)!r}).touch()"


def paper_circuit(tmp_path: Path, name='load', node='line', circuit_name='paper') -> Path:
    """The paper's circuit with a chosen load name, line node name and circuit name."""
    doc = {'name': circuit_name, 'plant': str(ROOT / 'config' / 'pump.yaml'), 'components': {
        'pump': {'type': 'pump', 'ports': {'out': node}},
        'line_volume': {'type': 'volume', 'ports': {'node': node}, 'V': 'plant.line.V_l'},
        name: {'type': 'orifice_load', 'ports': {'in': node}, 'mu': 'plant.line.mu_u',
               'gamma': 'plant.line.gamma_u', 'dp_cr': 'plant.line.dp_cr_u',
               'load_pressure': 'plant.line.P_u', 'aperture': 'plant.line.xi_u'},
        'relief': {'type': 'relief', 'ports': {'in': node, 'out': 'tank'},
                   'p_crack': 'plant.relief.p_crack', 'p_full': 'plant.relief.p_full',
                   'q_full': 'plant.relief.q_full'},
        'tank': {'type': 'tank', 'ports': {'node': 'tank'}}}}
    path = tmp_path / 'c.yaml'
    path.write_text(yaml.safe_dump(doc))
    return path


HOSTILE = ['x\n{payload}', 'a"""; {payload}; """', "b'); {payload} #", '__import__']


@pytest.mark.parametrize('where', ['component', 'node', 'circuit'])
@pytest.mark.parametrize('template', HOSTILE)
def test_hostile_names_are_refused_and_never_run(tmp_path, where, template):
    marker = tmp_path / 'ran'
    bad = template.format(payload=payload(marker))
    kw = {'component': 'name', 'node': 'node', 'circuit': 'circuit_name'}[where]
    path = paper_circuit(tmp_path, **{kw: bad})
    with pytest.raises(CircuitError) as err:
        load_circuit(path)
    lines = err.value.lines
    assert any(repr(bad) in ln and 'a letter, then letters, digits or _' in ln for ln in lines)
    assert all('\n' not in ln for ln in lines)
    assert not marker.exists()


def test_the_command_line_refuses_a_hostile_name_in_one_line(tmp_path):
    marker = tmp_path / 'ran'
    path = paper_circuit(tmp_path, name=f'x\n{payload(marker)}')
    r = subprocess.run([BIN / 'hydropump', 'circuit', str(path), '--duration', '0.01'],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 2, r.stderr
    assert 'Traceback' not in r.stderr
    assert 'a component name is a letter' in r.stderr
    assert not marker.exists()


def test_the_generated_source_holds_no_string_of_the_file(tmp_path):
    path = paper_circuit(tmp_path, name='zq_load_name', node='zq_node_name',
                         circuit_name='zq_circuit_name')
    circuit = load_circuit(path, compile=False)
    assert 'zq_load_name.flow' in circuit.signals  # the names are used ...
    for s in ('zq_load_name', 'zq_node_name', 'zq_circuit_name', str(path)):
        assert s not in circuit.code                # ... but never written into code


# ---- the cache ------------------------------------------------------------------------------

PROBE = textwrap.dedent("""\
    import sys
    from hydropump_sim.codecache import compile_module
    m = compile_module(sys.argv[1])
    print(m.__file__)
    print(m.VALUE)
    """)


def compile_probe(cache: Path, tmp: Path, code: str):
    env = {**os.environ, 'HYDROPUMP_CACHE': str(cache), 'TMPDIR': str(tmp)}
    r = subprocess.run([sys.executable, '-c', PROBE, code], capture_output=True, text=True,
                       env=env, timeout=120)
    assert r.returncode == 0, r.stderr
    path, value = r.stdout.split()
    # Less the notice of a first compile (a probe has no compiled code: every time).
    err = '\n'.join(ln for ln in r.stderr.splitlines()
                    if not ln.startswith(("compiling the circuit's equations", 'compiled in ')))
    return Path(path), value, err


def test_a_cache_folder_others_may_write_into_is_not_used(tmp_path):
    shared = tmp_path / 'shared'
    shared.mkdir()
    shared.chmod(0o777)
    tmp = tmp_path / 'tmp'
    tmp.mkdir()
    path, value, err = compile_probe(shared, tmp, 'VALUE = 41\n')
    assert value == '41'
    assert 'writable by others' in err and str(shared) in err
    assert tmp in path.parents and shared not in path.parents
    folder = tmp / f'hydropump-cache-{os.getuid()}'
    assert (folder.stat().st_mode & 0o777) == 0o700  # created owner-only


def test_a_tampered_cache_entry_is_written_anew_and_never_run(tmp_path):
    cache, tmp = tmp_path / 'cache', tmp_path / 'tmp'
    tmp.mkdir()
    code = 'VALUE = 42\n'
    path, value, err = compile_probe(cache, tmp, code)
    assert value == '42' and not err
    assert (cache.stat().st_mode & 0o777) == 0o700
    # Another source under the module's name: compared with the generated one, replaced.
    marker = tmp_path / 'ran'
    path.write_text(f'{payload(marker)}\nVALUE = 666\n')
    assert compile_probe(cache, tmp, code)[1] == '42'
    assert not marker.exists()
    # The module writable by others, and a numba index beside it writable by others.
    path.chmod(0o666)
    index = path.parent / '__pycache__' / f'{path.stem}.evaluate-5.py311.nbi'
    index.write_bytes(b'not a pickle of ours')
    index.chmod(0o666)
    _, value, err = compile_probe(cache, tmp, code)
    assert value == '42'
    assert f'ignored the cache entry {path}' in err and str(index) in err
    assert not index.exists() and (path.stat().st_mode & 0o022) == 0


@pytest.mark.skipif(os.getuid() != 0, reason='needs root to give a file to another user')
def test_a_cache_entry_of_another_user_is_ignored(tmp_path):
    cache, tmp = tmp_path / 'cache', tmp_path / 'tmp'
    tmp.mkdir()
    code = 'VALUE = 43\n'
    path, _, _ = compile_probe(cache, tmp, code)
    os.chown(path, 65534, 65534)
    _, value, err = compile_probe(cache, tmp, code)
    assert value == '43' and 'owned by uid 65534' in err
    assert path.stat().st_uid == os.getuid()
    # A whole cache folder of another user is skipped for the next one.
    os.chown(cache / 'circuits', 65534, 65534)
    path2, value, err = compile_probe(cache, tmp, code)
    assert value == '43' and 'owned by uid 65534' in err and cache not in path2.parents


# ---- YAML -----------------------------------------------------------------------------------

BOMB = textwrap.dedent("""\
    a: &a [x, x, x, x, x, x, x, x, x, x]
    b: &b [*a, *a, *a, *a, *a, *a, *a, *a, *a, *a]
    c: &c [*b, *b, *b, *b, *b, *b, *b, *b, *b, *b]
    d: &d [*c, *c, *c, *c, *c, *c, *c, *c, *c, *c]
    e: &e [*d, *d, *d, *d, *d, *d, *d, *d, *d, *d]
    f: &f [*e, *e, *e, *e, *e, *e, *e, *e, *e, *e]
    g: &g [*f, *f, *f, *f, *f, *f, *f, *f, *f, *f]
    h: &h [*g, *g, *g, *g, *g, *g, *g, *g, *g, *g]
    """)


def test_an_alias_bomb_is_refused_by_the_params_and_circuit_readers(tmp_path):
    params = tmp_path / 'bomb.yaml'
    params.write_text('pump:\n  ros__parameters:\n' + textwrap.indent(BOMB, '    '))
    with pytest.raises(ParamError) as err:
        load_params(params)
    assert 'expands to more than 200000 values' in err.value.lines[0]
    circuit = tmp_path / 'c.yaml'
    circuit.write_text(BOMB + 'components: {}\n')
    with pytest.raises(CircuitError) as err:
        load_circuit(circuit)
    assert 'expands to more than' in err.value.lines[0]


def test_a_key_given_twice_is_refused(tmp_path):
    text = (ROOT / 'config' / 'pump.yaml').read_text()
    twice = text.replace('ros__parameters:', 'ros__parameters:\n    line:\n      V_l: 1.0e-3',
                         1)
    assert twice != text
    path = tmp_path / 'twice.yaml'
    path.write_text(twice)
    with pytest.raises(ParamError) as err:
        load_params(path)
    assert "the key 'line' is given twice" in err.value.lines[0]


def test_an_oversized_yaml_file_is_refused_before_it_is_read(tmp_path):
    path = tmp_path / 'big.yaml'
    with path.open('w') as f:
        f.write('components:\n')
        f.write('# padding\n' * (MAX_YAML_BYTES // 10 + 1))
    with pytest.raises(CircuitError) as err:
        load_circuit(path)
    assert 'MiB a YAML file of this suite may hold' in err.value.lines[0]


def test_a_set_value_that_expands_is_refused_and_a_recursive_one_too():
    from hydropump_sim.schema import assignments
    bomb = '[' + ', '.join(['&a [1, 1, 1, 1, 1, 1, 1, 1, 1, 1]']
                           + [f'&{c} [' + ', '.join([f'*{p}'] * 10) + ']'
                              for p, c in zip('abcdef', 'bcdefg')]) + ']'
    with pytest.raises(ParamError) as err:
        assignments([f'a.b={bomb}'])
    assert 'expands to more than' in err.value.lines[0]
    with pytest.raises(ParamError) as err:
        assignments(['a.b=&x [1, *x]'])
    assert 'recursive alias' in err.value.lines[0]
    # A few shared values (what yaml.safe_dump writes for a repeated object) are fine.
    assert assignments(['a.b=[&x [1, 2], *x]']) == {'a.b': [[1, 2], [1, 2]]}


def test_a_params_file_header_quoting_text_with_line_breaks_stays_a_comment(tmp_path):
    """A params file's header quotes paths and command lines (a calibrated file's bags and
    provenance): a line break in one, of any kind YAML knows, never starts a line of YAML."""
    from hydropump_sim.params import default_params_path, load_params
    from hydropump_sim.schema import dump_ros_yaml
    p = load_params(default_params_path())
    for brk in ('\n', '\r', '\x85', '\u2028', '\u2029'):
        evil = f'bag{brk}/**:{brk}  ros__parameters:{brk}    line:{brk}      V_l: 9.0'
        text = dump_ros_yaml(p.flat(), header=f'# calibrated from {evil}')
        head = text[:text.index('\n/**:\n  ros__parameters:')]
        assert all(ln.startswith('#') for ln in head.splitlines() if ln.strip()), repr(head)
        path = tmp_path / 'p.yaml'
        path.write_text(text, encoding='utf-8')
        assert load_params(path).line.V_l == p.line.V_l
