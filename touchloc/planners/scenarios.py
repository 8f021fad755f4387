"""Ready-made localisation problems on the bundled meshes (demo, benchmarks, tests)."""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from .._util import as_rng
from ..errors import ValidationError
from .candidates import CandidateGenerator

__all__ = ["Scenario", "make_scenario", "SETTINGS"]

#: setting name -> description
SETTINGS = {
    "planar": "x, y in a 100 mm square and any yaw, the object standing on a table",
    "6dof": "x, y, z in a 60 mm cube and any rotation (SO(3))",
}


@dataclass
class Scenario:
    """An object, its measurement model, the prior region and a candidate generator."""

    obj: object
    model: object
    region: object
    candidates: CandidateGenerator
    setting: str

    def hidden_pose(self, rng=None) -> np.ndarray:
        """(4, 4) a true pose drawn uniformly from the region."""
        return self.region.sample(1, rng=as_rng(rng))[0]


def make_scenario(obj, setting: str = "planar", *, sigma_pos: float = 0.002, sigma_nor: float = 0.15,
                  n_world: int = 60, n_relative: int = 40, n_hands: int = 0, seed: int = 0) -> Scenario:
    """Build a :class:`Scenario` for a bundled mesh name or a MeshObject.

    Parameters
    ----------
    obj : str or MeshObject
    setting : {"planar", "6dof"}
        See :data:`SETTINGS`.
    sigma_pos, sigma_nor : float
        Proximity model noise.
    n_world, n_relative, n_hands : int
        Candidate pool sizes (see :class:`~touchloc.planners.candidates.CandidateGenerator`).
    """
    from ..belief import PoseRegion
    from ..models import MeshObject, ProximityModel

    if isinstance(obj, str):
        from ..data import load_object

        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            obj = load_object(obj)
    if not isinstance(obj, MeshObject):
        raise ValidationError(f"obj must be a bundled mesh name or a MeshObject, got {type(obj).__name__}")
    if not isinstance(setting, str):
        raise ValidationError(f"setting must be one of {sorted(SETTINGS)}, got {type(setting).__name__}")
    if setting == "planar":
        # standing on a table at z = 0
        region = PoseRegion.planar((0.0, 0.0), 0.05, z=-float(obj.bounds[0][2]))
    elif setting == "6dof":
        region = PoseRegion.box((0.0, 0.0, 0.0), 0.03, rotation="full")
    else:
        raise ValidationError(f"setting must be one of {sorted(SETTINGS)}, got {setting!r}")
    region = region.with_rho(obj.radius)
    model = ProximityModel(obj, sigma_pos, sigma_nor)
    gen = CandidateGenerator(region, obj, n_world=n_world, n_relative=n_relative, n_hands=n_hands, seed=seed)
    return Scenario(obj, model, region, gen, setting)
