"""Public faces of packages whose modules are heavy (torch): names imported on first use.

A package's ``__init__`` lists what it offers and where it lives; importing the package
stays cheap, and ``from rl.learners import DQNTrainer`` loads torch only then (PEP 562).
"""

from __future__ import annotations

import importlib
from typing import Any, Callable


def lazy_exports(
    package: str, where: dict[str, str]
) -> tuple[Callable[[str], Any], Callable[[], list[str]], list[str]]:
    """``__getattr__``, ``__dir__`` and ``__all__`` for `package`, which offers `where`'s names
    (name -> module that defines it)."""

    def __getattr__(name: str) -> Any:
        if name not in where:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        return getattr(importlib.import_module(where[name]), name)

    def __dir__() -> list[str]:
        return sorted(where)

    return __getattr__, __dir__, sorted(where)
