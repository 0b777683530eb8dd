"""Nothing a user made is overwritten by accident: an output equal to an input, inside a bag,
or over an existing file of another kind is refused with one line and the file is left as it
was (byte for byte); an output of the same kind is replaced whole, through a temporary file
renamed into place, and a write that fails (a full disk) leaves the old file and no debris."""

from pathlib import Path
import resource
import shutil
import signal

import pytest

from hydropump_ctrl.cli import main
from hydropump_sim import files

ROOT = Path(__file__).resolve().parents[2]
PUMP = ROOT / 'config' / 'pump.yaml'
CONTROLLER = ROOT / 'config' / 'controller.yaml'


def _run(capsys, *argv):
    code = main([str(a) for a in argv])
    cap = capsys.readouterr()
    return code, cap.out, cap.err.strip().splitlines()


def _debris(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.rglob('.*part-*'))


@pytest.fixture
def plant(tmp_path):
    path = tmp_path / 'pump.yaml'
    shutil.copy(PUMP, path)
    return path


def test_design_over_its_own_plant_file_is_refused_and_the_file_kept(capsys, plant):
    before = plant.read_bytes()
    code, _, err = _run(capsys, 'design', '--params', plant, '--out', plant)
    assert code == 2 and len(err) == 1, err
    assert err[0].startswith(f'error: params file {plant}: it exists and holds plant params, '
                             'not controller params')
    assert plant.read_bytes() == before


def test_design_over_another_plant_file_is_refused(capsys, plant, tmp_path):
    other = tmp_path / 'other_pump.yaml'
    shutil.copy(PUMP, other)
    before = other.read_bytes()
    code, _, err = _run(capsys, 'design', '--params', plant, '--out', other)
    assert code == 2 and len(err) == 1 and 'holds plant params' in err[0], err
    assert other.read_bytes() == before


@pytest.mark.parametrize('content, kind', [
    ('rosbag2_bagfile_information:\n  version: 9\n', 'bag metadata'),
    ('name: c\ncomponents: {}\n', 'circuit'),
    ('a: [1, 2\n', 'text that is not YAML'),
    ('- 1\n- 2\n', 'YAML of another kind'),
])
def test_design_over_a_yaml_of_another_kind_is_refused(capsys, plant, tmp_path, content,
                                                       kind):
    target = tmp_path / 'taken.yaml'
    target.write_text(content)
    code, _, err = _run(capsys, 'design', '--params', plant, '--out', target)
    assert code == 2 and len(err) == 1 and f'holds {kind}, not controller params' in err[0]
    assert target.read_text() == content


def test_design_replaces_a_controller_file_whole_and_leaves_no_debris(capsys, plant,
                                                                      tmp_path):
    target = tmp_path / 'controller.yaml'
    shutil.copy(CONTROLLER, target)
    target.write_text(target.read_text() + '# a line the new file does not have\n')
    code, _, err = _run(capsys, 'design', '--params', plant, '--out', target)
    assert code == 0, err
    text = target.read_text()
    assert 'a line the new file does not have' not in text and 'controller:' in text
    assert _debris(tmp_path) == []


def test_an_empty_file_may_be_replaced(capsys, plant, tmp_path):
    target = tmp_path / 'new.yaml'
    target.write_text('')
    assert _run(capsys, 'design', '--params', plant, '--out', target)[0] == 0
    assert 'controller:' in target.read_text()


def test_simulate_over_a_csv_of_other_data_is_refused(capsys, tmp_path):
    sc = tmp_path / 'step.yaml'
    sc.write_text('duration: 0.05\ninputs:\n  current: 0.5\n')
    data = tmp_path / 'measured.csv'
    data.write_text('time,pressure\n0,1\n')
    code, _, err = _run(capsys, 'simulate', sc, '--out', data)
    assert code == 2 and len(err) == 1 and 'holds CSV of other data' in err[0], err
    assert data.read_text() == 'time,pressure\n0,1\n'
    # A results CSV of an earlier run is the same kind: replaced.
    result = tmp_path / 'result.csv'
    assert _run(capsys, 'simulate', sc, '--out', result)[0] == 0
    first = result.read_text()
    assert _run(capsys, 'simulate', sc, '--out', result)[0] == 0
    assert result.read_text() == first and _debris(tmp_path) == []


@pytest.fixture
def bag_folder(tmp_path):
    """A folder holding what marks a rosbag2 bag: metadata.yaml beside an .mcap file."""
    bag = tmp_path / 'bag'
    bag.mkdir()
    (bag / 'metadata.yaml').write_text('rosbag2_bagfile_information:\n  version: 9\n')
    (bag / 'bag_0.mcap').write_bytes(b'\x89MCAP0\r\n')
    return bag


@pytest.mark.parametrize('argv', [
    ['simulate', '{sc}', '--out', '{bag}/result.csv'],
    ['analyze', '--out', '{bag}/analysis'],
    ['analyze', '--out', '{bag}'],
])
def test_an_output_inside_a_bag_is_refused(capsys, tmp_path, bag_folder, argv):
    sc = tmp_path / 'step.yaml'
    sc.write_text('duration: 0.05\ninputs:\n  current: 0.5\n')
    before = sorted(p.name for p in bag_folder.iterdir())
    code, _, err = _run(capsys, *[a.format(sc=sc, bag=bag_folder) for a in argv])
    assert code == 2 and len(err) == 1, err
    assert f'it lies in the bag {bag_folder}; choose a path outside it' in err[0]
    assert sorted(p.name for p in bag_folder.iterdir()) == before


def _limit_file_size(limit: int):
    """Writes past ``limit`` bytes fail with EFBIG (a full disk, for this process alone)."""
    old = resource.getrlimit(resource.RLIMIT_FSIZE), signal.signal(signal.SIGXFSZ,
                                                                     signal.SIG_IGN)
    resource.setrlimit(resource.RLIMIT_FSIZE, (limit, old[0][1]))
    return old


def _restore(old):
    resource.setrlimit(resource.RLIMIT_FSIZE, old[0])
    signal.signal(signal.SIGXFSZ, old[1])


def test_a_write_that_fails_keeps_the_old_file_and_says_why_in_one_line(tmp_path):
    target = tmp_path / 'result.csv'
    target.write_text('old\n')
    old = _limit_file_size(1000)
    try:
        with pytest.raises(files.WriteError) as err:
            files.write_text(target, 'x' * 5000, 'result')
    finally:
        _restore(old)
    assert err.value.lines == [f'cannot write the result {target}: File too large']
    assert target.read_text() == 'old\n' and _debris(tmp_path) == []


def test_an_interrupted_writer_keeps_the_old_file(tmp_path):
    target = tmp_path / 'fig.png'
    target.write_bytes(b'old')
    with pytest.raises(KeyboardInterrupt):
        with files.replacing(target) as tmp:
            tmp.write_bytes(b'half of a new')
            raise KeyboardInterrupt
    assert target.read_bytes() == b'old' and _debris(tmp_path) == []


def test_a_figure_takes_its_format_from_the_target_name(tmp_path):
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    fig = plt.figure()
    try:
        files.save_figure(fig, tmp_path / 'a.png')
        files.save_figure(fig, tmp_path / 'a.svg')
    finally:
        plt.close(fig)
    assert (tmp_path / 'a.png').read_bytes()[:8] == b'\x89PNG\r\n\x1a\n'
    assert b'<svg' in (tmp_path / 'a.svg').read_bytes()[:500]

