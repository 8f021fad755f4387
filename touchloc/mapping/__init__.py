"""Shape maps of unknown objects from touch, active exploration, and localisation against them.

>>> from touchloc.mapping import ShapeMap, explore, chamfer_distance
>>> smap = ShapeMap((lo, hi), method="gpis")     # doctest: +SKIP
>>> smap.update(results)                         # doctest: +SKIP
>>> mesh = smap.to_mesh()                        # doctest: +SKIP
"""

from .._lazy import attach

#: where each public name is defined; imported on first use (see touchloc._lazy)
_NAMES = {
    "explore": ("PLANNERS", "ExplorationRun", "box_pool", "explore", "hand_pool", "lattice_pool", "ray_information"),
    "metrics": ("chamfer_distance", "fscore", "surface_distances"),
    "shape_map": ("ShapeMap",),
    "slam": ("TactileSLAM", "transform_results"),
    "world": ("MovingWorld",),
    "superquadric": ("Superquadric", "fit_superquadric"),
}

__all__ = [
    "ShapeMap", "TactileSLAM", "MovingWorld", "transform_results", "explore", "ExplorationRun", "ray_information", "box_pool", "hand_pool", "lattice_pool", "PLANNERS",
    "fit_superquadric", "Superquadric", "chamfer_distance", "fscore", "surface_distances",
]

__getattr__, __dir__ = attach(__name__, _NAMES)
