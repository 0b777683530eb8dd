"""The ament index a venv gets (``make``): the bringup's share folder as colcon's
--symlink-install lays it out, subfolders included."""

from pathlib import Path
import sysconfig

from hydropump_ros.venv_index import install

from ..conftest import ROOT


def test_the_bringup_share_folder_holds_every_config_file_and_the_circuits(tmp_path):
    # A prefix of its own (the venv's layout: the index's .pth goes to its site-packages).
    for key in ('purelib', 'platlib'):
        d = sysconfig.get_paths(vars={'base': str(tmp_path), 'platbase': str(tmp_path)})[key]
        Path(d).mkdir(parents=True, exist_ok=True)
    install(ROOT, tmp_path)
    share = tmp_path / 'share' / 'hydropump_bringup'
    config = ROOT / 'config'
    # Every file of config/, at any depth, as a link to the one source (the Fig. 1 launch
    # file loads config/circuits/fig1.yaml from the share folder).
    want = sorted(f.relative_to(config) for f in config.rglob('*') if f.is_file())
    got = sorted(f.relative_to(share / 'config') for f in (share / 'config').rglob('*')
                 if f.is_symlink())
    assert got == want and (share / 'config' / 'circuits' / 'fig1.yaml') in {
        share / 'config' / g for g in got}
    assert (share / 'config' / 'circuits' / 'fig1.yaml').resolve() == \
        (config / 'circuits' / 'fig1.yaml').resolve()
    assert (share / 'launch' / 'fig1.launch.py').is_symlink()
    # Run again over what it wrote (make runs it at every install): the same links.
    install(ROOT, tmp_path)
    assert sorted(f.relative_to(share / 'config') for f in (share / 'config').rglob('*')
                  if f.is_symlink()) == want
