"""The one base class of every error a user can cause.

A user mistake (a bad parameter, scenario, bag or command line) raises a subclass of
:class:`HydropumpError`, whose ``lines`` are shown one per line, with no traceback, by every
entry point (the ``hydropump`` command line, the nodes at start-up, ``hydropump-demo``).
Anything else that escapes is a bug and keeps its traceback.
"""

from __future__ import annotations

from collections.abc import Iterable


class HydropumpError(Exception):
    """A user-facing error: ``lines`` holds one human-readable line per problem.

    Parameters
    ----------
    lines : str or iterable of str
        The problem(s), each a complete sentence without a trailing newline.
    source : str, optional
        The file or object the problems are in; shown in the message head.
    """

    #: Head of the message (``'invalid parameters'``); ``None`` joins the lines alone.
    head: str | None = None

    def __init__(self, lines: str | Iterable[str], source: str | None = None):
        self.lines = [lines] if isinstance(lines, str) else [str(x) for x in lines]
        self.source = source
        if self.head is None:
            text = '; '.join(self.lines)
            text = f'{source}: {text}' if source else text
        else:
            head = f'{self.head} in {source}' if source else self.head
            text = head + ':\n' + '\n'.join('  ' + ln for ln in self.lines)
        super().__init__(text)

    def __reduce__(self):
        return (type(self), (self.lines, self.source))


class InputError(HydropumpError, ValueError):
    """A bad argument to a library function (a duration, a grid, a signal out of range)."""
