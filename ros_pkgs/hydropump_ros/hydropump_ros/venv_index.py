"""Register the suite in the ament index of a Python prefix (the project's ``.venv``).

``colcon build`` installs the ament index marker, ``package.xml``, launch files, config and the
executables under ``lib/<package>``. An editable pip install does none of that, so ``make``
runs this module once after installing (links, like ``colcon build --symlink-install``):
afterwards ``ament_index_python`` finds the packages
in ``.venv`` and ``<prefix>/lib/hydropump_ros/simulator`` is an executable, as ``ros2 run``
expects. A ``.pth`` file adds the prefix to ``AMENT_PREFIX_PATH`` for the venv's Python.
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path
import shutil
import sys
import sysconfig

PACKAGES = {
    'hydropump_sim': 'hydropump_sim',
    'hydropump_ctrl': 'hydropump_ctrl',
    'hydropump_ros': 'ros_pkgs/hydropump_ros',
    'hydropump_bringup': 'ros_pkgs/hydropump_bringup',
}
EXECUTABLES = {'hydropump_ros': ('simulator', 'controller', 'recorder', 'foxglove',
                              'hydropump-graph')}
SHARE_DIRS = {'hydropump_bringup': ('launch', 'config')}

# The executables under lib/hydropump_ros. The venv's ROS wheels set their library path by
# re-executing Python from a .pth file at site import, where a Ctrl-C is a fatal error with a
# traceback, or is lost. This launcher sets that path itself and starts Python with SIGINT and
# SIGTERM blocked (coreutils env --block-signal: blocked before the interpreter runs a line),
# so a signal stays pending through its start until the node's own handlers take it
# (entry.py unblocks them). A signal to the shell before that ends it quietly.
LAUNCHER = """#!/bin/sh
# Written by hydropump_ros.venv_index (make): the node {name}, as ros2 run starts it.
LD_LIBRARY_PATH="{libs}${{LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}}"
export LD_LIBRARY_PATH _ROS_WHEELS_BOOTSTRAP_COMPLETE=1
exec env --block-signal=INT --block-signal=TERM {python} -c \\
    'import sys; sys.argv = sys.argv[1:]; import hydropump_ros.entry as e; sys.exit(e.{func}())' \\
    "$0" "$@"
"""
# Entry points of the node executables (the others are links to the console scripts).
NODES = {'simulator': 'simulator', 'controller': 'controller', 'recorder': 'recorder',
         'foxglove': 'foxglove'}

PTH = """import os, sys; p = os.environ.get('AMENT_PREFIX_PATH', ''); \
os.environ['AMENT_PREFIX_PATH'] = p if sys.prefix in p.split(os.pathsep) \
else os.pathsep.join(x for x in (p, sys.prefix) if x)
"""


def install(root: Path, prefix: Path) -> list[Path]:
    """Write the index entries under ``prefix`` for the source tree at ``root``."""
    written = []
    index = prefix / 'share' / 'ament_index' / 'resource_index' / 'packages'
    index.mkdir(parents=True, exist_ok=True)
    for pkg, rel in PACKAGES.items():
        src = root / rel
        (index / pkg).write_text('')
        share = prefix / 'share' / pkg
        share.mkdir(parents=True, exist_ok=True)
        shutil.copy2(src / 'package.xml', share / 'package.xml')
        written.append(index / pkg)
        for sub in SHARE_DIRS.get(pkg, ()):
            dst = share / sub
            if dst.is_symlink() or dst.is_file():
                dst.unlink()
            elif dst.is_dir():
                shutil.rmtree(dst)
            # Folders of links to the files, as colcon's --symlink-install makes them: the
            # sources stay the one copy, and ros2 launch, which walks the share folder
            # without following links to folders, finds the launch files; subfolders too
            # (config/circuits, which the Fig. 1 launch file loads).
            base = (src / sub).resolve()
            for f in sorted(base.rglob('*')):
                if f.is_file():
                    link = dst / f.relative_to(base)
                    link.parent.mkdir(parents=True, exist_ok=True)
                    link.symlink_to(f)
                    written.append(link)
            dst.mkdir(exist_ok=True)
        for exe in EXECUTABLES.get(pkg, ()):
            lib = prefix / 'lib' / pkg
            lib.mkdir(parents=True, exist_ok=True)
            link = lib / exe
            if link.is_symlink() or link.exists():
                link.unlink()
            if exe in NODES:
                site = Path(sysconfig.get_paths(vars={'base': str(prefix),
                                                      'platbase': str(prefix)})['purelib'])
                libs = [prefix / 'lib', *sorted(d for d in site.glob('ros_*.libs')
                                                if d.is_dir())]
                text = LAUNCHER.format(python=prefix / 'bin' / 'python', name=exe,
                                       func=NODES[exe],
                                       libs=os.pathsep.join(str(d) for d in libs))
                # The venv's own bin/<node> too, in place of pip's console script: started
                # from there (.venv/bin/simulator), a Ctrl-C in its first milliseconds was
                # the same fatal error at site import.
                (prefix / 'bin').mkdir(exist_ok=True)
                for path in (link, prefix / 'bin' / exe):
                    if path.is_symlink():
                        path.unlink()
                    path.write_text(text)
                    path.chmod(0o755)
                    written.append(path)
                continue
            link.symlink_to(os.path.relpath(prefix / 'bin' / exe, lib))
            written.append(link)
    pth = Path(sysconfig.get_paths(vars={'base': str(prefix), 'platbase': str(prefix)})
               ['purelib']) / 'hydropump_ament_prefix.pth'
    pth.write_text(PTH)
    written.append(pth)
    return written


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--root', default='.', help='source tree (default: current directory)')
    ap.add_argument('--prefix', default=sys.prefix, help='install prefix (default: this venv)')
    args = ap.parse_args(argv)
    for path in install(Path(args.root).resolve(), Path(args.prefix).resolve()):
        print(f'  {path}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
