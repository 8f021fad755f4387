"""Shape maps of unknown objects from touch, active exploration, and localisation against them.

>>> from touchloc.mapping import ShapeMap, explore, chamfer_distance
>>> smap = ShapeMap((lo, hi), method="gpis")     # doctest: +SKIP
>>> smap.update(results)                         # doctest: +SKIP
>>> mesh = smap.to_mesh()                        # doctest: +SKIP
"""

from .explore import PLANNERS, ExplorationRun, box_pool, explore, hand_pool, lattice_pool, ray_information
from .metrics import chamfer_distance, fscore, surface_distances
from .shape_map import ShapeMap
from .slam import MovingWorld, TactileSLAM, transform_results
from .superquadric import Superquadric, fit_superquadric

__all__ = [
    "ShapeMap", "TactileSLAM", "MovingWorld", "transform_results", "explore", "ExplorationRun", "ray_information", "box_pool", "hand_pool", "lattice_pool", "PLANNERS",
    "fit_superquadric", "Superquadric", "chamfer_distance", "fscore", "surface_distances",
]
