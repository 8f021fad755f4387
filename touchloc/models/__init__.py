"""What the world is: object meshes, contacts, measurement and dynamics models."""

from .._lazy import attach

#: where each public name is defined; imported on first use (see touchloc._lazy)
_NAMES = {
    "base": ("MeasurementModel", "SumModel"),
    "contacts": ("Contacts",),
    "dynamics": ("GaussianDynamics",),
    "freespace": ("FreeSpaceBase", "FreeSpaceModel", "RayStopModel", "TouchLikelihood", "ray_stops"),
    "integrated": ("IntegratedProximityModel",),
    "mesh": ("MeshObject", "MeshRepairWarning", "MeshUnitsWarning"),
    "proximity": ("ProximityModel", "contacts_in_object_frame"),
    "symmetry": ("Symmetry",),
}

__all__ = [
    "Contacts", "MeshObject", "MeshRepairWarning", "MeshUnitsWarning", "MeasurementModel",
    "SumModel", "ProximityModel", "IntegratedProximityModel", "FreeSpaceModel",
    "FreeSpaceBase", "RayStopModel", "TouchLikelihood", "ray_stops",
    "GaussianDynamics", "contacts_in_object_frame", "Symmetry",
]

__getattr__, __dir__ = attach(__name__, _NAMES)
