"""The repository stands alone: no tracked file refers to a file outside it.

Every tracked text file (code, tests, docs, config) is scanned. A failure lists each offender
as ``path:line: what: text``; the fix is to cite the project's own document instead
(``docs/reference.md`` for the reading of the paper and the reference figures, ``docs/model.md``
for the model as implemented) or the project's own test data (``tests/data``).
"""

from pathlib import Path
import re
import subprocess

import pytest

from ..conftest import ROOT

# Written so that this file does not match its own patterns.
OUTSIDE = [
    (re.compile(r'model[_ ]notes', re.I), 'notes outside the repository'),
    (re.compile(r'\.\.[/\\]shared|\bshared[/\\](?:reference|guides|seed|hooks)\b'),
     'shared folder outside the repository'),
    (re.compile(r'(?<![\w.~-])/(?:home|work|root|mnt|Users)/'), 'absolute path of a machine'),
    (re.compile(r'\bROOT\.parent\b'), 'path above the repository root'),
]
# An issue by number, a tracker address, or the definite article before the word, which here
# always stands for a tracker entry.
ISSUES = re.compile(r'\bissues?\s*#?\s*I?\d+|/(?:issues|pull)/\d+|\bthe issue\b', re.I)
PARENTS = re.compile(r'Path\(__file__\)(?:\.resolve\(\))?\.parents\[(\d+)\]')
UP = re.compile(r'(?<![\w.])((?:\.\./)+)[\w.-]+')
MD_LINK = re.compile(r'\]\(([^)\s]+)\)')
CITATION = re.compile(r'reference\.md(?:#|\s+§?\s*)([IDA]\d{1,2})\b', re.I)
# Reference data the tests read; each must be a tracked file under tests/data.
DATA_FILES = ('pump_reference.yaml',)


def _tracked():
    try:
        out = subprocess.run(['git', 'ls-files', '-z'], cwd=ROOT, capture_output=True,
                             check=True).stdout.decode()
        names = [n for n in out.split('\0') if n]
    except (OSError, subprocess.CalledProcessError):  # not a git checkout: walk the tree
        skip = {'.git', '.venv', 'build', 'install', 'log', 'out', 'bags', '__pycache__'}
        names = [p.relative_to(ROOT).as_posix() for p in ROOT.rglob('*')
                 if p.is_file() and not skip & set(p.relative_to(ROOT).parts)]
    assert names, 'no tracked files found'
    return sorted(names)


def _text_files():
    """``(relative path, lines)`` of every tracked text file."""
    files = []
    for name in _tracked():
        path = ROOT / name
        if not path.is_file():  # deleted in the work tree, not yet in the index
            continue
        data = path.read_bytes()
        if b'\0' in data:
            continue
        try:
            files.append((name, data.decode('utf-8').splitlines()))
        except UnicodeDecodeError:
            continue
    return files


def _inside(path: Path) -> bool:
    return path.resolve().is_relative_to(ROOT)


def _report(title, offenders):
    return '\n'.join([f'{title} ({len(offenders)}):'] + offenders)


def _line(name, k, what, text):
    return f'{name}:{k}: {what}: {text.strip()[:120]}'


def test_no_reference_outside_the_repository():
    tracked = set(_tracked())
    data = {Path(n).name for n in tracked if n.startswith('tests/data/')}
    offenders = []
    for name, lines in _text_files():
        here = (ROOT / name).parent
        depth = len(Path(name).parts) - 1
        for k, text in enumerate(lines, 1):
            what = [w for pattern, w in OUTSIDE if pattern.search(text)]
            if any(int(m[1]) > depth for m in PARENTS.finditer(text)):
                what.append('path above the repository root')
            what += [f'relative path {m[0]} leaves the repository' for m in UP.finditer(text)
                     if not _inside(here / m[0])]
            what += [f'{f} is not in tests/data' for f in DATA_FILES
                     if f in text and f not in data]
            if what:
                offenders.append(_line(name, k, '; '.join(what), text))
    if offenders:
        pytest.fail(_report('references to files outside the repository', offenders),
                    pytrace=False)


def test_no_issue_tracker_references():
    """Code and docs describe the project itself, not entries of an issue tracker."""
    offenders = [_line(name, k, 'issue tracker', text)
                 for name, lines in _text_files() for k, text in enumerate(lines, 1)
                 if ISSUES.search(text)]
    if offenders:
        pytest.fail(_report('mentions of issue-tracker entries', offenders), pytrace=False)


def _anchors(md: Path) -> set[str]:
    """Explicit ``<a id>`` anchors and GitHub's heading anchors of a markdown file."""
    text = md.read_text()
    ids = set(re.findall(r'<a id="([^"]+)"', text))
    for heading in re.findall(r'^#+\s+(.*)$', text, re.M):
        slug = re.sub(r'<[^>]+>', '', heading).strip().lower()
        ids.add(re.sub(r'\s', '-', re.sub(r'[^\w\s-]', '', slug)))
    return ids


def test_document_links_and_citations_resolve():
    """Markdown links point at tracked files (and existing anchors); every citation of
    docs/reference.md names one of its items."""
    tracked = set(_tracked())
    folders = {p.as_posix() for n in tracked for p in Path(n).parents}
    reference = ROOT / 'docs' / 'reference.md'
    assert reference.as_posix()[len(ROOT.as_posix()) + 1:] in tracked
    items = _anchors(reference)
    offenders = []
    for name, lines in _text_files():
        here = (ROOT / name).parent
        for k, text in enumerate(lines, 1):
            for m in CITATION.finditer(text):
                if m[1].lower() not in items:
                    offenders.append(_line(name, k, f'no item {m[1]} in docs/reference.md',
                                           text))
            if not name.endswith('.md'):
                continue
            for m in MD_LINK.finditer(text):
                target = m[1]
                if re.match(r'[a-z]+:', target):
                    continue
                file_part, _, anchor = target.partition('#')
                path = (here / file_part) if file_part else ROOT / name
                if not _inside(path):
                    offenders.append(_line(name, k, f'link {target} leaves the repository',
                                           text))
                    continue
                rel = path.resolve().relative_to(ROOT).as_posix()
                if rel not in tracked and rel not in folders:
                    offenders.append(_line(name, k, f'link {target}: no such file', text))
                elif anchor and rel.endswith('.md') and anchor not in _anchors(path):
                    offenders.append(_line(name, k, f'link {target}: no such anchor', text))
    if offenders:
        pytest.fail(_report('broken links or citations', offenders), pytrace=False)
