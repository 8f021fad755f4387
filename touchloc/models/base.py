"""The measurement-model interface and the composition of models."""

from __future__ import annotations

import numpy as np

from .._util import as_poses
from .._validate import as_sequence
from ..errors import ValidationError

__all__ = ["MeasurementModel", "SumModel", "check_temperature"]


def check_temperature(temperature) -> float:
    try:
        T = float(temperature)
    except (TypeError, ValueError):
        raise ValidationError(f"temperature must be a positive finite number, got {temperature!r}") from None
    if not (np.isfinite(T) and T > 0):
        raise ValidationError(f"temperature must be a positive finite number, got {temperature!r}")
    return T


class MeasurementModel:
    """Something that scores object poses given measurements.

    Subclasses implement :meth:`log_likelihood`. Models add: ``a + b`` is a
    :class:`SumModel` whose log-likelihood is the sum (independent measurements).
    """

    #: the MeshObject the model describes (every model in touchloc has one)
    obj = None

    def log_likelihood(self, poses, contacts=None, temperature: float = 1.0) -> np.ndarray:
        """(N,) log p(measurements | pose) / temperature, up to a pose-independent constant."""
        raise NotImplementedError

    def __add__(self, other: "MeasurementModel") -> "SumModel":
        if not isinstance(other, MeasurementModel):
            return NotImplemented
        return SumModel([self, other])

    def _poses(self, poses) -> np.ndarray:
        return as_poses(poses)


class SumModel(MeasurementModel):
    """Sum of the log-likelihoods of several models (independent measurements).

    Every model receives the same ``contacts`` argument; models that carry their own
    data (e.g. :class:`~touchloc.models.FreeSpaceModel`) ignore it.
    """

    def __init__(self, models):
        flat = []
        for m in as_sequence(models, "models", expected="a list of measurement models"):
            if not isinstance(m, MeasurementModel):
                raise ValidationError(f"SumModel takes measurement models, got {type(m).__name__}")
            flat.extend(m.models if isinstance(m, SumModel) else [m])
        if not flat:
            raise ValidationError("SumModel needs at least one model")
        self.models = flat
        self.obj = flat[0].obj

    def log_likelihood(self, poses, contacts=None, temperature: float = 1.0) -> np.ndarray:
        poses = self._poses(poses)
        total = np.zeros(len(poses))
        for m in self.models:
            total += m.log_likelihood(poses, contacts, temperature)
        return total

    def __repr__(self) -> str:
        return " + ".join(repr(m) for m in self.models)
