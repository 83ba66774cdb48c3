"""Extension points named by parameters: ``module.path:attribute`` -> the object there.

Nodes pick an arm or an audio source by name from a registry; a name of this form imports
one from any module on the Python path instead, so adding one needs no edit of the
package (docs/design.md, "Extending").
"""

from __future__ import annotations

import importlib
from typing import Any, Callable, Optional


def is_reference(name: str) -> bool:
    """True when ``name`` has the ``module.path:attribute`` form."""
    module, sep, attr = name.partition(":")
    return bool(sep and module and attr)


def load(name: str, choices: str,
         accept: Optional[Callable[[Any], bool]] = callable) -> Any:
    """The object at ``module.path:attribute``.

    Raises ValueError saying that ``name`` is none of ``choices`` (the registry's names)
    when it has another form, and why when it cannot be imported or ``accept`` refuses it
    (by default anything not callable).
    """
    if not is_reference(name):
        raise ValueError(f"{name!r} is not {choices} nor a module.path:attribute")
    module, _, attr = name.partition(":")
    try:
        obj = getattr(importlib.import_module(module), attr)
    except (ImportError, AttributeError) as exc:
        raise ValueError(f"cannot import {name!r}: {exc}") from exc
    if accept is not None and not accept(obj):
        raise ValueError(f"{name!r} is not what is expected here ({type(obj).__name__})")
    return obj
