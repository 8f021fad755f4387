"""Bundled real object meshes (robosuite, MIT; pybullet_data, zlib: see the LICENSE files).

>>> from touchloc.data import mesh_path, MESHES
>>> mesh_path("mug")  # doctest: +ELLIPSIS
PosixPath('.../touchloc/data/meshes/mug.obj')
"""

from __future__ import annotations

from pathlib import Path

from ..errors import ValidationError

_DIR = Path(__file__).resolve().parent / "meshes"

#: name -> scale that brings the file to metres (bunny.obj is stored in decimetres).
MESHES = {
    "bread": 1.0,
    "can": 1.0,
    "cereal": 1.0,
    "lemon": 1.0,
    "milk": 1.0,
    "mug": 1.0,
    "bunny": 0.1,
}


def mesh_path(name: str) -> Path:
    """Path of a bundled mesh file, by name (see :data:`MESHES`)."""
    if name not in MESHES:
        raise ValidationError(f"unknown bundled mesh {name!r}; choose from {sorted(MESHES)}")
    return _DIR / f"{name}.obj"


def load_object(name: str, **kwargs):
    """A :class:`touchloc.models.MeshObject` of a bundled mesh, scaled to metres."""
    from ..models import MeshObject

    return MeshObject.from_file(mesh_path(name), scale=MESHES[name], name=name, **kwargs)
