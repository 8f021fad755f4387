"""What the world is: object meshes, contacts, measurement and dynamics models."""

from .base import MeasurementModel, SumModel
from .contacts import Contacts
from .mesh import MeshObject, MeshRepairWarning, MeshUnitsWarning
from .proximity import ProximityModel

__all__ = [
    "Contacts", "MeshObject", "MeshRepairWarning", "MeshUnitsWarning", "MeasurementModel",
    "SumModel", "ProximityModel",
]
