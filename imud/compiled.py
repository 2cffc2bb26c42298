"""The compiled kernels: C versions of a few hot per-read steps, built at install time when a C
compiler is there (pyproject.toml's ext-modules, each optional).

Each kernel has a NumPy twin beside its caller, which is the reference (the results are the
same to the bit: tests/test_compiled.py) and what runs when the kernel was not built, or with
IMUD_PURE_PYTHON=1 in the environment (to compare, or to rule the kernels out). A device about
to stream logs a warning, once a process, for each kernel module asked for and not found
(`warn_missing`): it works, at a higher CPU cost a sample.
"""

from __future__ import annotations

import importlib
import logging
import os
from types import ModuleType

log = logging.getLogger("imud")
PURE_ENV = "IMUD_PURE_PYTHON"
_tried: dict[str, bool] = {}  # module -> whether it loaded


def pure() -> bool:
    """Whether the NumPy twins are asked for in place of every kernel."""
    return os.environ.get(PURE_ENV, "") not in ("", "0")


def load(name: str) -> ModuleType | None:
    """The compiled module `name`, or None (not built here, or the NumPy twins asked for)."""
    if pure():
        _tried[name] = False
        return None
    try:
        module = importlib.import_module(name)
    except ImportError:
        _tried[name] = False
        return None
    _tried[name] = True
    return module


def warn_missing() -> None:
    """Log, once a process for each, the kernels asked for and not found: a device about to
    stream says so (a command that merely imports a module does not)."""
    new = [n for n in missing() if n not in _warned]
    if new:
        _warned.update(new)
        log.warning(
            "compiled kernels not built: %s. Their NumPy twins run instead, at a higher CPU "
            "cost a sample. Install a C compiler and Python's headers (Debian: build-essential "
            "python3-dev) and reinstall imud (docs/performance.md)",
            ", ".join(new),
        )


_warned: set[str] = set()


def missing() -> list[str]:
    """The kernels asked for in this process that did not load, with the NumPy twins not asked
    for (those are not missing, only unused)."""
    return [] if pure() else sorted(n for n, ok in _tried.items() if not ok)
