"""Draw docs/img/architecture.png from the project's own import graph.

    .venv/bin/python docs/draw_architecture.py

The modules of the three packages are scanned with ``ast`` (nothing is imported), grouped
into the units ``docs/architecture.md`` describes, and drawn as three layers: the ROS
package, which uses the control package, which uses the plant package; an arrow is an
import between units.
"""

from __future__ import annotations

import ast
from collections import defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = {'hydropump_ros': ROOT / 'ros_pkgs' / 'hydropump_ros' / 'hydropump_ros',
            'hydropump_ctrl': ROOT / 'hydropump_ctrl' / 'hydropump_ctrl',
            'hydropump_sim': ROOT / 'hydropump_sim' / 'hydropump_sim'}
# Units: package -> [(unit, label, module prefixes)], top to bottom.
UNITS = {
    'hydropump_ros': [
        ('nodes', 'simulator_node  controller_node\nrecorder_node',
         ('simulator_node', 'controller_node', 'recorder_node')),
        ('edge', 'bridge  entry  conversions\n(schema -> ROS, start/stop)',
         ('bridge', 'entry', 'conversions')),
        ('orchestration', 'campaign  graph  orchestration\ncommand_line  (processes)',
         ('campaign', 'graph', 'venv_index', 'orchestration', 'record', 'command_line')),
    ],
    'hydropump_ctrl': [
        ('cli', 'cli/  fmi/\n(hydropump command, FMU export)', ('cli', 'fmi')),
        ('demo', 'demo/\n(campaign, duty cycles, report)', ('demo', 'pages')),
        ('experiments', 'experiments/  plans\n(harnesses, cases, plans)',
         ('experiments', 'experiment', 'plans')),
        ('control', 'control/\n(EMC, PI, design, supervisor)', ('control',)),
        ('ident', 'ident/\n(recordings, FOPDT fits, report)', ('ident',)),
        ('recorder', 'recorder/  bag/\n(sequencer, rosbag2 bags)', ('recorder', 'bag')),
        ('timebase', 'timebase\n(the rule of time)', ('timebase',)),
    ],
    'hydropump_sim': [
        ('runner', 'runner  measure\n(what a simulator node does)', ('runner', 'measure')),
        ('analysis', 'linear  reduction  paper\nanalysis  metrics', ('linear', 'reduction',
                                                                'paper', 'analysis',
                                                                'metrics', 'scaling')),
        ('simulate', 'simulate  steady  trim  invariants\nenergy  sensors  schedule',
         ('simulate', 'steady', 'trim', 'invariants', 'energy', 'scenario', 'sensors',
          'schedule', 'inputs')),
        ('model', 'system.Model: plant_model\ncircuit  components/', ('system', 'plant_model',
                                                                   'circuit', 'components',
                                                                   'model', '_core')),
        ('schema', 'params  schema  errors\n(one schema for everything)',
         ('params', 'schema', 'errors')),
    ],
}
COLOURS = {'hydropump_ros': '#dbe9f6', 'hydropump_ctrl': '#e3f1dc', 'hydropump_sim': '#fbe8d3'}


def _module_name(pkg: str, path: Path) -> str:
    rel = path.relative_to(PACKAGES[pkg]).with_suffix('')
    parts = [p for p in rel.parts if p != '__init__']
    return '.'.join([pkg, *parts])


def _unit_of(module: str) -> tuple[str, str] | None:
    pkg, _, rest = module.partition('.')
    for unit, _, prefixes in UNITS.get(pkg, ()):
        if any(rest == p or rest.startswith(p + '.') for p in prefixes):
            return pkg, unit
    return None


def import_edges() -> dict[tuple, int]:
    """``{(from unit, to unit): number of imports}`` between units."""
    edges: dict[tuple, int] = defaultdict(int)
    for pkg, base in PACKAGES.items():
        for path in sorted(base.rglob('*.py')):
            mod = _module_name(pkg, path)
            src = _unit_of(mod)
            if src is None:
                continue
            package = mod if path.name == '__init__.py' else mod.rpartition('.')[0]
            for node in ast.walk(ast.parse(path.read_text())):
                targets = []
                if isinstance(node, ast.Import):
                    targets = [a.name for a in node.names]
                elif isinstance(node, ast.ImportFrom):
                    if node.level:
                        up = package.split('.')
                        head = '.'.join(up[:len(up) - node.level + 1])
                        name = f'{head}.{node.module}' if node.module else head
                        targets = [name] + [f'{name}.{a.name}' for a in node.names]
                    else:
                        targets = [node.module] + [f'{node.module}.{a.name}'
                                                   for a in node.names]
                for t in targets:
                    dst = _unit_of(t)
                    if dst is not None and dst != src:
                        edges[(src, dst)] += 1
                        break
    return dict(edges)


def draw(path: Path) -> Path:
    import matplotlib
    matplotlib.use('Agg')
    from matplotlib.patches import FancyArrowPatch, FancyBboxPatch
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(13, 8))
    ax.set_xlim(0, 13.8)
    ax.set_ylim(0, 8.4)
    ax.axis('off')
    pos = {}
    w, h = 3.2, 0.95
    for col, (pkg, units) in enumerate(UNITS.items()):
        x = 0.5 + col * 4.4
        ax.add_patch(FancyBboxPatch((x - 0.2, 0.2), w + 0.4, 7.6, boxstyle='round,pad=0.05',
                                    fc=COLOURS[pkg], ec='0.6', lw=1.0, zorder=0))
        ax.text(x + w / 2, 7.95, pkg, ha='center', va='bottom', fontsize=12,
                fontweight='bold')
        step = 7.2 / len(units)
        for i, (unit, label, _) in enumerate(units):
            y = 7.4 - (i + 1) * step + (step - h) / 2
            ax.add_patch(FancyBboxPatch((x, y), w, h, boxstyle='round,pad=0.03', fc='white',
                                        ec='0.3', lw=1.0, zorder=2))
            ax.text(x + w / 2, y + h / 2, label, ha='center', va='center', fontsize=8.5,
                    zorder=3)
            pos[(pkg, unit)] = (x, y)
    for (src, dst), n in sorted(import_edges().items()):
        (xs, ys), (xd, yd) = pos[src], pos[dst]
        if xs == xd:  # within a package: along the right-hand side
            a, b = (xs + w, ys + h / 2), (xd + w, yd + h / 2)
            style = 'arc3,rad=-0.35'
        else:
            a, b = (xs + w, ys + h / 2), (xd, yd + h / 2)
            # An arrow that skips the middle layer bends around it.
            style = 'arc3,rad=-0.18' if xd - xs > 5.0 else 'arc3,rad=0.0'
        ax.add_patch(FancyArrowPatch(a, b, connectionstyle=style, arrowstyle='-|>',
                                     mutation_scale=9, lw=0.6 + 0.15 * min(n, 8),
                                     color='0.35', alpha=0.45, zorder=1))
    ax.text(0.3, 0.0, 'Arrows: imports between units (thicker: more of them). Only '
            'hydropump_ros imports ROS; imports go left to right, never back.',
            fontsize=8.5, color='0.3')
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


if __name__ == '__main__':
    print(draw(ROOT / 'docs' / 'img' / 'architecture.png'))
