"""Module layout: no private name imported from another module, no import cycle in a package.

Both rules are checked on the source with ``ast``; nothing is imported, so the ROS package is
scanned like the pure ones. Every import counts, at module level or inside a function: a
lazy import hides a cycle from the interpreter, not from the design. ``__import__('x')`` and
``importlib.import_module('x')`` with a literal name count as imports of ``x``.

A private module of a package (``hydropump_sim._core``) may be imported by the modules of that
package: it is private to the package, not to a module.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PACKAGES = {
    'hydropump_sim': ROOT / 'hydropump_sim' / 'hydropump_sim',
    'hydropump_ctrl': ROOT / 'hydropump_ctrl' / 'hydropump_ctrl',
    'hydropump_ros': ROOT / 'ros_pkgs' / 'hydropump_ros' / 'hydropump_ros',
}
# Other Python code of the project, checked for private imports (scripts and tests import
# the packages like any user).
OTHER = [ROOT / 'tests', ROOT / 'bench', ROOT / 'ros_pkgs' / 'hydropump_bringup']


# ---- the scan -------------------------------------------------------------------------------

def module_files(src: Path, name: str) -> dict[str, Path]:
    """Dotted module name -> file for the package ``name`` whose folder is ``src``."""
    out = {}
    for f in sorted(src.rglob('*.py')):
        parts = [name, *f.relative_to(src).with_suffix('').parts]
        if parts[-1] == '__init__':
            parts.pop()
        out['.'.join(parts)] = f
    return out


def _dotted(f: Path, base: Path) -> tuple[str, bool]:
    """Dotted name of a file below ``base`` and whether it is a package's ``__init__``."""
    parts = list(f.relative_to(base).with_suffix('').parts)
    is_pkg = parts[-1] == '__init__'
    return '.'.join(parts[:-1] if is_pkg else parts), is_pkg


def _resolve(module: str | None, level: int, importer: str, is_pkg: bool) -> str:
    """Absolute name of ``from <level dots><module> import ...`` written in ``importer``."""
    if level == 0:
        return module or ''
    parts = importer.split('.')
    # A package's __init__ is its own package; a module's package is its parent.
    keep = len(parts) - (level - 1) - (0 if is_pkg else 1)
    base = parts[:max(keep, 0)]
    return '.'.join(base + ([module] if module else []))


def imports(source: str, importer: str, is_pkg: bool) -> list[tuple[str, list[str], int]]:
    """Every import in ``source``: ``(absolute module, names taken from it, line)``."""
    out = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            out += [(a.name, [], node.lineno) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = _resolve(node.module, node.level, importer, is_pkg)
            out.append((base, [a.name for a in node.names], node.lineno))
        elif isinstance(node, ast.Call) and node.args and isinstance(node.args[0], ast.Constant) \
                and isinstance(node.args[0].value, str) and not node.args[0].value.startswith('.'):
            f = node.func
            dynamic = (isinstance(f, ast.Name) and f.id == '__import__') or (
                isinstance(f, ast.Attribute) and f.attr == 'import_module'
                and isinstance(f.value, ast.Name) and f.value.id == 'importlib')
            if dynamic:
                out.append((node.args[0].value, [], node.lineno))
    return out


def _private(name: str) -> bool:
    return name.startswith('_') and not (name.startswith('__') and name.endswith('__'))


def private_imports(files: dict[str, tuple[Path, bool]], modules: set[str]
                    ) -> list[tuple[str, str, str, int]]:
    """``(importer, module, name, line)`` of every private name taken from another module.

    ``files`` maps dotted names to ``(file, is_package)``; ``modules`` are all known module
    names, so that a private submodule taken by a module of its own package is allowed.
    """
    bad = []
    for importer, (f, is_pkg) in files.items():
        for base, names, line in imports(f.read_text(), importer, is_pkg):
            for n in names:
                own_module = f'{base}.{n}' in modules and importer.startswith(base + '.')
                if _private(n) and not own_module:
                    bad.append((importer, base, n, line))
    return bad


def import_graph(mods: dict[str, Path]) -> dict[str, set[str]]:
    """Edges between the modules of one package (to a submodule where one is named)."""
    graph: dict[str, set[str]] = {m: set() for m in mods}

    def target(name: str) -> str | None:
        while name and name not in mods:
            name = name.rpartition('.')[0]
        return name or None

    for m, f in mods.items():
        is_pkg = f.name == '__init__.py'
        for base, names, _ in imports(f.read_text(), m, is_pkg):
            for t in ([target(f'{base}.{n}') if f'{base}.{n}' in mods else target(base)
                       for n in names] or [target(base)]):
                if t is not None and t != m:
                    graph[m].add(t)
    return graph


def cycles(graph: dict[str, set[str]]) -> list[frozenset[str]]:
    """Strongly connected components of more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[frozenset[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = set()
            while True:
                w = stack.pop()
                on.discard(w)
                comp.add(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(frozenset(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def _project_files() -> tuple[dict[str, tuple[Path, bool]], set[str]]:
    files: dict[str, tuple[Path, bool]] = {}
    for name, src in PACKAGES.items():
        for m, f in module_files(src, name).items():
            files[m] = (f, f.name == '__init__.py')
    modules = set(files)
    for base in OTHER:
        for f in sorted(base.rglob('*.py')):
            dotted, is_pkg = _dotted(f, ROOT)
            files[dotted] = (f, is_pkg)
    return files, modules


# ---- the rules on the project ---------------------------------------------------------------

def test_no_private_name_is_imported_from_another_module():
    files, modules = _project_files()
    found = [f'{files[imp][0].relative_to(ROOT)}:{line}: from {mod} import {name}'
             for imp, mod, name, line in private_imports(files, modules)]
    assert not found, found


@pytest.mark.parametrize('pkg', sorted(PACKAGES))
def test_no_import_cycle_inside_a_package(pkg):
    graph = import_graph(module_files(PACKAGES[pkg], pkg))
    assert len(graph) > 3
    found = [sorted(c) for c in cycles(graph)]
    assert not found, found


def test_the_identification_package_takes_nothing_private_and_has_no_cycle():
    # The identification code on its own: nothing private in or out, no cycle among its
    # modules.
    mods = module_files(PACKAGES['hydropump_ctrl'] / 'ident', 'hydropump_ctrl.ident')
    assert {'hydropump_ctrl.ident.recording', 'hydropump_ctrl.ident.robust',
            'hydropump_ctrl.ident.paper'} <= set(mods)
    files, modules = _project_files()
    assert not [x for x in private_imports(files, modules) if x[0].startswith(
        'hydropump_ctrl.ident') or x[1].startswith('hydropump_ctrl.ident')]
    graph = import_graph(module_files(PACKAGES['hydropump_ctrl'], 'hydropump_ctrl'))
    ident = {m: {t for t in e if t.startswith('hydropump_ctrl.ident')}
             for m, e in graph.items() if m.startswith('hydropump_ctrl.ident')}
    assert not cycles(ident)


def test_bags_have_one_home_that_the_recorder_and_identification_share():
    """hydropump_ctrl.bag reads, writes and names the errors of bags; the recorder and
    identification take their bags from it and neither imports the other; the bag package
    takes nothing of either."""
    graph = import_graph(module_files(PACKAGES['hydropump_ctrl'], 'hydropump_ctrl'))

    def takes(prefix, other):
        return {(m, t) for m, e in graph.items() if m.startswith(prefix)
                for t in e if t.startswith(other)}
    for a, b in (('hydropump_ctrl.ident', 'hydropump_ctrl.recorder'),
                 ('hydropump_ctrl.recorder', 'hydropump_ctrl.ident'),
                 ('hydropump_ctrl.bag', 'hydropump_ctrl.ident'),
                 ('hydropump_ctrl.bag', 'hydropump_ctrl.recorder')):
        assert not takes(a, b), takes(a, b)
    assert takes('hydropump_ctrl.ident', 'hydropump_ctrl.bag')
    assert takes('hydropump_ctrl.recorder', 'hydropump_ctrl.bag')
    from hydropump_ctrl import bag, ident, recorder
    assert ident.BagError is recorder.BagError is bag.BagError
    assert issubclass(bag.BagReadError, ValueError) and issubclass(bag.BagWriteError, OSError)
    assert issubclass(ident.PlausibilityError, bag.BagReadError)


def test_nothing_below_the_demo_application_imports_it():
    """demo/ is the demo application: identification, control, bags, the recorder, the
    offline harnesses (experiments/) and the recording plans (a file format identification
    reads) stand below it and take nothing from it."""
    graph = import_graph(module_files(PACKAGES['hydropump_ctrl'], 'hydropump_ctrl'))
    below = ('ident', 'control', 'bag', 'recorder', 'plans', 'experiment', 'experiments')

    def under(name, part):
        return name == f'hydropump_ctrl.{part}' or name.startswith(f'hydropump_ctrl.{part}.')
    up = {(m, t) for m, e in graph.items() if any(under(m, b) for b in below)
          for t in e if under(t, 'demo')}
    assert not up, up
    assert 'hydropump_ctrl.plans' in graph['hydropump_ctrl.ident.design']


def test_each_command_module_takes_only_the_shared_helpers_from_the_cli():
    graph = import_graph(module_files(PACKAGES['hydropump_ctrl'], 'hydropump_ctrl'))
    cli = 'hydropump_ctrl.cli'
    groups = ('plant', 'circuit', 'fit', 'calibrate', 'control', 'record', 'sweep', 'fmu')
    for group in groups:
        assert {t for t in graph[f'{cli}.{group}'] if t.startswith(cli)} == {f'{cli}.options'}
    # The package itself: each command module, and the shared parser.
    assert {t for t in graph[cli] if t.startswith(cli)} == {f'{cli}.{g}' for g in groups} | {
        f'{cli}.options'}
    assert not {t for t in graph[f'{cli}.options'] if t.startswith('hydropump_ctrl')}


# ---- the scan itself --------------------------------------------------------------------------

def _write(root: Path, files: dict[str, str]) -> None:
    for rel, text in files.items():
        p = root / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(text)


def test_scan_finds_private_imports_and_cycles(tmp_path):
    _write(tmp_path / 'pkg', {
        '__init__.py': 'from .a import f\n',
        '_core.py': 'X = 1\n',
        'a.py': 'from . import _core\nfrom .b import _helper\n\ndef f():\n    from . import c\n',
        'b.py': 'def _helper():\n    pass\n',
        'c.py': 'import pkg.a\n',
        'd.py': "__import__('pkg.e')\n",
        'e.py': 'from pkg import d\nfrom .b import __doc__\n',
        'sub/__init__.py': 'from .. import _core\nfrom ._x import y\n',
        'sub/_x.py': 'y = 1\n',
    })
    mods = module_files(tmp_path / 'pkg', 'pkg')
    files = {m: (f, f.name == '__init__.py') for m, f in mods.items()}
    found = {(i, m, n) for i, m, n, _ in private_imports(files, set(mods))}
    # _helper is private to b; _core and sub._x are private modules of their own packages.
    assert found == {('pkg.a', 'pkg.b', '_helper')}
    graph = import_graph(mods)
    assert graph['pkg.a'] == {'pkg._core', 'pkg.b', 'pkg.c'}
    assert graph['pkg.sub'] == {'pkg._core', 'pkg.sub._x'}
    # a -> c is lazy (inside a function) and still closes the cycle; d -> e is dynamic.
    assert sorted(map(sorted, cycles(graph))) == [['pkg.a', 'pkg.c'], ['pkg.d', 'pkg.e']]


def test_relative_imports_resolve_from_modules_and_packages():
    assert _resolve('b', 1, 'p.q.a', False) == 'p.q.b'
    assert _resolve('b', 1, 'p.q', True) == 'p.q.b'
    assert _resolve(None, 2, 'p.q.a', False) == 'p'
    assert _resolve('x.y', 0, 'p.a', False) == 'x.y'


def _signal_lists(path: Path, names: set[str]) -> list[str]:
    """Literal lists of three or more measured signals in ``path`` (a tuple, list, set or
    dict's keys), components' ``MEASURES`` declarations left out."""
    tree = ast.parse(path.read_text())
    declared = {id(n.value) for n in ast.walk(tree) if isinstance(n, ast.Assign)
                and any(isinstance(t, ast.Name) and t.id == 'MEASURES' for t in n.targets)}
    out = []
    for node in ast.walk(tree):
        if isinstance(node, (ast.Tuple, ast.List, ast.Set)):
            elts = node.elts
        elif isinstance(node, ast.Dict) and id(node) not in declared:
            elts = [k for k in node.keys if k is not None]
        else:
            continue
        hit = [e.value for e in elts if isinstance(e, ast.Constant) and e.value in names]
        if len(hit) >= 3:
            out.append(f'{path}:{node.lineno}: {hit}')
    return out


def test_the_measured_signals_are_listed_in_one_place(tmp_path):
    """measure.SIGNALS is the one table of the measured signals: every other list of them
    (flows, pressures, a recorder's topics) is derived from it, not written again, so that
    a signal added there reaches every reader. A component says which of its own signals
    are which measured signal (``MEASURES``); that declaration is its own."""
    from hydropump_sim.measure import SIGNALS
    names = set(SIGNALS)
    home = ROOT / 'hydropump_sim' / 'hydropump_sim' / 'measure.py'
    found = [hit for folder in PACKAGES.values() for path in sorted(folder.rglob('*.py'))
             if path != home for hit in _signal_lists(path, names)]
    assert not found, 'a second list of measured signals:\n' + '\n'.join(found)
    # The check finds one (a tuple of three, written by hand).
    probe = tmp_path / 'probe.py'
    probe.write_text("X = ('line_flow', 'pump_flow', 'load_flow')\n")
    assert _signal_lists(probe, names)


# The words only a schedule parser reads from a mapping (hydropump_sim.schedule's keys).
SCHEDULE_WORDS = {'steps', 'ramp', 'staircase', 'dwell', 'levels', 'amplitude'}


def _key_read(node: ast.AST) -> str | None:
    """The constant key ``node`` reads from a mapping: ``x['k']``, ``x.get('k')``, ``'k' in
    x``."""
    if isinstance(node, ast.Subscript) and isinstance(node.ctx, ast.Load) and \
            isinstance(node.slice, ast.Constant):
        return node.slice.value
    if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and \
            node.func.attr == 'get' and node.args and isinstance(node.args[0], ast.Constant):
        return node.args[0].value
    if isinstance(node, ast.Compare) and isinstance(node.left, ast.Constant) and \
            any(isinstance(op, (ast.In, ast.NotIn)) for op in node.ops):
        return node.left.value
    return None


def _schedule_reads(path: Path) -> list[str]:
    """Functions in ``path`` that read two or more schedule words from mappings (one alone
    is another concept's key: Morris ``levels``, a results table's ``steps``)."""
    out = []
    for fn in ast.walk(ast.parse(path.read_text())):
        if not isinstance(fn, (ast.FunctionDef, ast.AsyncFunctionDef)):
            continue
        words = {k for node in ast.walk(fn) if (k := _key_read(node)) in SCHEDULE_WORDS}
        if len(words) >= 2:
            out.append(f'{path}:{fn.lineno} {fn.name}: reads {sorted(words)}')
    return out


def test_input_schedules_have_one_parser(tmp_path):
    """hydropump_sim.schedule is the one reader of scheduled inputs: scenarios, recording
    plans and sweeps call it, so a staircase means one thing everywhere. A module that reads
    a schedule's keys itself is a second parser."""
    home = ROOT / 'hydropump_sim' / 'hydropump_sim' / 'schedule.py'
    found = [hit for folder in PACKAGES.values() for path in sorted(folder.rglob('*.py'))
             if path != home for hit in _schedule_reads(path)]
    assert not found, 'a second parser of input schedules:\n' + '\n'.join(found)
    # The check finds each way of reading a key.
    probe = tmp_path / 'probe.py'
    for reads in ("raw['dwell'], raw.get('levels')", "'ramp' in raw or 'steps' in raw"):
        probe.write_text(f'def f(raw):\n    return {reads}\n')
        assert _schedule_reads(probe), reads


#: The longest a function of the pure packages may be (its code, the docstring left out)
#: without a comment saying why it is long ("long on purpose").
LONG_FUNCTION = 80


def _long_functions(path: Path) -> list[str]:
    lines = path.read_text().splitlines()
    out = []
    for fn in ast.walk(ast.parse('\n'.join(lines))):
        if not isinstance(fn, (ast.FunctionDef, ast.AsyncFunctionDef)):
            continue
        body = fn.body
        doc = isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant) \
            and isinstance(body[0].value.value, str) and len(body) > 1
        first = body[1] if doc else body[0]
        code = lines[first.lineno - 1:fn.end_lineno]
        whole = lines[fn.lineno - 1:fn.end_lineno]
        if len(code) > LONG_FUNCTION and not any('long on purpose' in ln for ln in whole):
            out.append(f'{path}:{fn.lineno} {fn.name}: {len(code)} lines')
    return out


def test_long_functions_of_the_pure_packages_say_why(tmp_path):
    """A function of more than LONG_FUNCTION lines in hydropump_sim or hydropump_ctrl is
    split by concern, or says in a comment why it is one (a compiled loop, one pass along a
    hydraulic path)."""
    found = [hit for name in ('hydropump_sim', 'hydropump_ctrl')
             for path in sorted(PACKAGES[name].rglob('*.py')) for hit in _long_functions(path)]
    assert not found, 'long functions without a reason:\n' + '\n'.join(found)
    probe = tmp_path / 'probe.py'
    probe.write_text('def f():\n    """Doc."""\n' + '    x = 1\n' * (LONG_FUNCTION + 1))
    assert _long_functions(probe)
    probe.write_text('def f():\n    # long on purpose\n' + '    x = 1\n' * LONG_FUNCTION)
    assert not _long_functions(probe)
