"""Circuit components, one module per component type (see :mod:`.base` for the contract).

:func:`registry` finds every :class:`~.base.Component` subclass with a ``kind`` in the
modules of this package: a new component type is one new module and nothing else.
"""

from __future__ import annotations

import functools
import importlib
import inspect
import pkgutil

from .base import Component

__all__ = ['Component', 'registry']

# Modules of this package that hold no component type.
_HELPERS = {'base', 'laws'}


@functools.cache
def registry() -> dict[str, type[Component]]:
    """Every component type by its ``kind``."""
    kinds: dict[str, type[Component]] = {}
    for info in pkgutil.iter_modules(__path__):
        if info.name in _HELPERS or info.name.startswith('_'):
            continue
        module = importlib.import_module(f'{__name__}.{info.name}')
        for _, cls in inspect.getmembers(module, inspect.isclass):
            if issubclass(cls, Component) and cls.kind and cls.__module__ == module.__name__:
                kinds[cls.kind] = cls
    return dict(sorted(kinds.items()))
