"""touchloc: Bayesian tactile localisation and mapping.

Subpackages: :mod:`touchloc.models` (meshes, contacts, measurement and dynamics models),
:mod:`touchloc.belief` (beliefs and estimators), :mod:`touchloc.planners` (where to touch
next), :mod:`touchloc.dnf` (dynamic neural fields), :mod:`touchloc.hardware` (SDH-2 hand
and DSACON32m tactile sensors) and :mod:`touchloc.recognition` (identification by touch).
"""

from __future__ import annotations

import importlib

from . import errors
from .errors import (
    BeliefDegenerateError,
    HardwareError,
    HardwareTimeout,
    MeshError,
    PlanningError,
    ProtocolError,
    TouchlocError,
    ValidationError,
)

__version__ = "0.1.0"

#: subpackages imported on first use (``tl.models``, ``tl.belief``, ...): ``import touchloc``
#: stays cheap, and the ``touchloc`` command imports only what its subcommand needs
_LAZY = {"geometry", "models", "belief", "planners", "dnf", "hardware", "recognition", "mapping", "experiments",
         "data", "cli"}


def __getattr__(name):
    if name in _LAZY:
        return importlib.import_module(f".{name}", __name__)
    raise AttributeError(f"module 'touchloc' has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | _LAZY)


__all__ = [
    "errors", "geometry", "models", "TouchlocError", "ValidationError", "MeshError",
    "BeliefDegenerateError", "PlanningError", "HardwareError", "HardwareTimeout", "ProtocolError",
]
