"""What the world is: object meshes, contacts, measurement and dynamics models."""

from .base import MeasurementModel, SumModel
from .contacts import Contacts
from .dynamics import GaussianDynamics
from .freespace import FreeSpaceBase, FreeSpaceModel, RayStopModel, TouchLikelihood, ray_stops
from .integrated import IntegratedProximityModel
from .mesh import MeshObject, MeshRepairWarning, MeshUnitsWarning
from .proximity import ProximityModel, contacts_in_object_frame
from .symmetry import Symmetry

__all__ = [
    "Contacts", "MeshObject", "MeshRepairWarning", "MeshUnitsWarning", "MeasurementModel",
    "SumModel", "ProximityModel", "IntegratedProximityModel", "FreeSpaceModel",
    "FreeSpaceBase", "RayStopModel", "TouchLikelihood", "ray_stops",
    "GaussianDynamics", "contacts_in_object_frame", "Symmetry",
]
