"""How the package compiles: the numba decorators every compiled function uses, and an
on-disk cache kept honest.

``jit``: cached, no GIL, numpy's error model (a division by zero gives inf or nan, which
the stepper rejects, instead of a branch and an exception in every division); ``inline``:
the same, inlined into its callers; ``cfunc(signature)``: a function the stepper takes as
a first-class argument.

numba keys a cached function on its own source file only: when a function it calls from
another module changes (a component's kernel called by the plant or by a generated
circuit), the cached machine code would be stale. :func:`guard` stamps the package's
sources and, when they changed since the stamp, drops the package's cached machine code
(every compiled module imports this one first, so it runs before any cached code loads);
:data:`DIGEST` goes into every generated circuit's source, so a circuit compiled against
older components is never reused.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import numba

jit = numba.njit(cache=True, fastmath=False, nogil=True, error_model='numpy')
inline = numba.njit(cache=True, fastmath=False, nogil=True, error_model='numpy',
                    inline='always')


def cfunc(signature):
    return numba.cfunc(signature, cache=True, nogil=True, error_model='numpy')


ROOT = Path(__file__).resolve().parent


def _digest() -> str:
    h = hashlib.sha256()
    for f in sorted(ROOT.rglob('*.py')):
        h.update(str(f.relative_to(ROOT)).encode())
        h.update(f.read_bytes())
    return h.hexdigest()[:16]


DIGEST = _digest()


def guard() -> None:
    stamp = ROOT / '__pycache__' / 'numba-sources.stamp'
    try:
        if stamp.read_text() == DIGEST:
            return
    except OSError:
        pass
    try:
        for f in ROOT.rglob('__pycache__/*.nb[ci]'):
            f.unlink(missing_ok=True)
        stamp.parent.mkdir(exist_ok=True)
        stamp.write_text(DIGEST)
    except OSError:
        pass  # a read-only install: numba keeps its cache elsewhere, per its own rules


guard()
