"""Reading a user's FMU (``hydropump fmu --check``, hydropump_ctrl.fmi.reading): an FMU
this suite did not write (a small orifice load written here with PythonFMU) read with its
variables; and each kind of bad file refused in one line naming the file and what is
missing, before FMPy parses or extracts it."""

import re
import subprocess
import sys
import zipfile

import pytest

from hydropump_ctrl.fmi import reading
from hydropump_ctrl.fmi.export import FmuError
from hydropump_ctrl.fmi.reading import read_fmu

from .. import fmus

pytest.importorskip('fmpy')
pytest.importorskip('pythonfmu')

@pytest.fixture(scope='module')
def orifice(tmp_path_factory):
    return fmus.build(tmp_path_factory.mktemp('orifice'), 'Orifice', fmus.ORIFICE)


def _rewrite(src, dest, drop=(), change=None):
    """A copy of the FMU ``src`` without the entries ``drop`` (prefixes), its model
    description passed through ``change``."""
    with zipfile.ZipFile(src) as zin, zipfile.ZipFile(dest, 'w') as zout:
        for e in zin.infolist():
            if any(e.filename.startswith(p) for p in drop):
                continue
            data = zin.read(e)
            if e.filename == 'modelDescription.xml' and change:
                data = change(data.decode()).encode()
            zout.writestr(e, data)
    return dest


def test_an_fmu_of_another_author_is_read_with_its_variables(orifice):
    info = read_fmu(orifice, inputs=['pressure'], outputs=['flow'])
    assert info.fmi_version == '2.0' and info.model_identifier == 'Orifice'
    assert (info.of('input'), info.of('output'), info.of('parameter')) == \
        (['pressure'], ['flow'], ['Cd_A'])
    assert info.variables['Cd_A'].start == pytest.approx(2.0e-6)


def test_check_lists_what_the_fmu_holds(orifice):
    proc = subprocess.run([sys.executable, '-m', 'hydropump_ctrl.cli', 'fmu', '--check',
                           str(orifice)], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    out = proc.stdout.splitlines()
    assert out[0] == f'{orifice}: FMI 2.0 co-simulation, model Orifice (PythonFMU 0.7.0)'
    assert '  1 inputs' in out and '    pressure, start 1e+07' in out
    assert '    Cd_A, start 2e-06' in out


@pytest.mark.parametrize('make, line', [
    (lambda src, d: (d / 'a.fmu').write_text('not a zip') and d / 'a.fmu',
     'a.fmu: not an FMU: not a zip archive'),
    (lambda src, d: _rewrite(src, d / 'a.fmu', drop=('modelDescription.xml',)),
     'a.fmu: no modelDescription.xml: not an FMU'),
    (lambda src, d: _rewrite(src, d / 'a.fmu', change=lambda x: re.sub(
        r'<CoSimulation.*?(/>|</CoSimulation>)', '', x, flags=re.S)),
     'a.fmu: neither co-simulation nor model exchange: nothing the suite runs'),
    (lambda src, d: _rewrite(src, d / 'a.fmu', drop=('binaries/linux64',)),
     'a.fmu: no binary for this platform (linux64): built for win64'),
    (lambda src, d: _rewrite(src, d / 'a.fmu', change=lambda x: x[:len(x) // 2]),
     'a.fmu: modelDescription.xml: '),
    (lambda src, d: d / 'none.fmu', 'none.fmu: no such file'),
])
def test_a_bad_fmu_is_one_line_naming_the_file(orifice, tmp_path, make, line):
    path = make(orifice, tmp_path)
    with pytest.raises(FmuError) as info:
        read_fmu(path)
    lines = info.value.lines
    assert len(lines) == 1 and line in lines[0] and lines[0].startswith(str(tmp_path)), lines


def test_a_variable_the_mapping_names_must_be_there(orifice):
    with pytest.raises(FmuError) as info:
        read_fmu(orifice, inputs=['pressure', 'P_in'], outputs=['q'])
    assert info.value.lines == [
        f'{orifice}: no input named P_in (its inputs: pressure)',
        f'{orifice}: no output named q (its outputs: flow)']


def test_a_file_beyond_the_bounds_is_refused_before_it_is_parsed(orifice, tmp_path,
                                                                    monkeypatch):
    """The archive's table says how much each entry unpacks to: the bounds are judged on it,
    before anything is read (a zip of zeros can unpack to gigabytes)."""
    monkeypatch.setattr(reading, 'MAX_DESCRIPTION', 100)
    with pytest.raises(FmuError, match=r'modelDescription.xml is .* MiB: more than'):
        read_fmu(orifice)
    monkeypatch.setattr(reading, 'MAX_ENTRIES', 2)
    with pytest.raises(FmuError, match=r'entries: more than an FMU holds \(at most 2 read\)'):
        read_fmu(orifice)
    bomb = tmp_path / 'bomb.fmu'
    with zipfile.ZipFile(bomb, 'w', zipfile.ZIP_DEFLATED) as z:
        z.writestr('modelDescription.xml', b'\0' * (8 * 2 ** 20))
    monkeypatch.setattr(reading, 'MAX_ENTRIES', 100_000)
    monkeypatch.setattr(reading, 'MAX_DESCRIPTION', 4 * 2 ** 20)
    assert bomb.stat().st_size < 100_000
    with pytest.raises(FmuError, match='modelDescription.xml is 8 MiB: more than 4 MiB'):
        read_fmu(bomb)
