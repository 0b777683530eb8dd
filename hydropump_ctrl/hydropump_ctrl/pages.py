"""The HTML of the suite's report pages (the demo's ``report.html``, a sweep's): one page
template, and tables whose every cell is escaped. A report's content (names from a user's
files included) reaches the page only through :func:`table`, :func:`section` or
``html.escape``, never as markup.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
import html
from string import Template

PAGE = Template('<!doctype html><html><head><meta charset="utf-8"><title>$title</title>'
                '<style>$css</style></head><body>$body</body></html>')


def table(head: Sequence, rows: Iterable[Sequence]) -> str:
    """An HTML table, every cell escaped."""
    h = ''.join(f'<th>{html.escape(str(x))}</th>' for x in head)
    body = ''.join('<tr>' + ''.join(f'<td>{html.escape(str(x))}</td>' for x in r) + '</tr>'
                   for r in rows)
    return f'<table><tr>{h}</tr>{body}</table>'


def section(title: str, body: str) -> str:
    """A titled part of a page: ``body`` is HTML, the title is escaped."""
    return f'<h2>{html.escape(title)}</h2>{body}'


def page(title: str, css: str, parts: Iterable[str]) -> str:
    """The whole page: ``parts`` (HTML, one after the other) under the escaped ``title``."""
    return PAGE.substitute(title=html.escape(title), css=css, body='\n'.join(parts))
