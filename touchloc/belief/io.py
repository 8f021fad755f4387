"""Save a localisation result to one ``.npz`` file and read it back.

The file holds plain arrays (no pickles), so numpy alone reads it from any language
binding: ``poses`` (N, 4, 4), ``log_weights`` (N,), ``map_pose`` (4, 4), the region
(``region_center``, ``region_half_extent``, ``region_rotation`` as a string or a (3, 3)
matrix, ``region_base_rotation``, ``region_yaw_range``, ``region_rho``), the contacts
(``contact_points`` (K, 3), ``contact_normals`` (K, 3) when measured), the model
parameters as a JSON string ``model`` and ``degenerate``/``resolution``.
"""

from __future__ import annotations

import json
import zipfile
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from .._validate import as_mapping, as_path, as_pose
from ..errors import ValidationError
from ..models import Contacts
from .particles import ParticleBelief
from .region import PoseRegion

__all__ = ["save_belief", "load_belief", "pose_to_dict", "FORMAT_VERSION"]

#: bumped when the file layout changes incompatibly
FORMAT_VERSION = 1


def pose_to_dict(T) -> dict:
    """A pose as plain JSON-ready lists: ``matrix`` (4x4), ``quat_xyzw``, ``translation`` (m).

    Parameters
    ----------
    T : (4, 4) float
        T_world_object.
    """
    T = as_pose(T, "pose")
    return {"matrix": T.tolist(), "quat_xyzw": Rotation.from_matrix(T[:3, :3]).as_quat().tolist(),
            "translation": T[:3, 3].tolist()}


def save_belief(path, belief: ParticleBelief, *, contacts: Contacts | None = None, model=None,
                extra: dict | None = None) -> Path:
    """Write ``belief`` (and what produced it) to ``path`` (.npz).

    Parameters
    ----------
    path : str or Path
        Output file; ``.npz`` is appended by numpy when missing.
    belief : ParticleBelief
    contacts : Contacts, optional
        The measurements the belief was computed from.
    model : measurement model, optional
        Its ``sigma_pos``, ``sigma_nor``, class name and mesh name are stored.
    extra : dict, optional
        More JSON-serialisable facts (e.g. the estimator's name).

    Returns
    -------
    Path of the written file.
    """
    if not isinstance(belief, ParticleBelief):
        raise ValidationError(f"belief must be a ParticleBelief, got {type(belief).__name__}")
    path = as_path(path, "path", must_exist=False)
    extra = {} if extra is None else as_mapping(extra, "extra")
    out = {"format_version": np.int64(FORMAT_VERSION), "poses": belief.poses, "log_weights": belief.log_weights,
           "map_pose": belief.map_pose(), "degenerate": np.bool_(belief.degenerate),
           "resolution": np.float64(np.nan if belief.resolution is None else belief.resolution)}
    reg = belief.region
    if reg is not None:
        out.update(region_center=reg.center, region_half_extent=reg.half_extent,
                   region_base_rotation=reg.base_rotation, region_yaw_range=np.asarray(reg.yaw_range),
                   region_rho=np.float64(np.nan if reg.rho is None else reg.rho))
        out["region_rotation"] = reg.fixed_rotation if reg.rotation == "fixed" else np.str_(reg.rotation)
    if contacts is not None:
        if not isinstance(contacts, Contacts):
            raise ValidationError(f"contacts must be Contacts, got {type(contacts).__name__}")
        out["contact_points"] = contacts.points
        if contacts.has_normals:
            out["contact_normals"] = contacts.normals
    meta = dict(extra)
    if model is not None:
        meta["model"] = {"class": type(model).__name__, "sigma_pos": getattr(model, "sigma_pos", None),
                         "sigma_nor": getattr(model, "sigma_nor", None),
                         "outlier_distance": getattr(model, "outlier_distance", None),
                         "mesh": getattr(getattr(model, "obj", None), "name", None)}
    try:
        out["meta"] = np.str_(json.dumps(meta))
    except (TypeError, ValueError) as exc:
        raise ValidationError(f"extra must be JSON-serialisable: {exc}") from None
    try:
        np.savez(path, **out)
    except OSError as exc:
        raise ValidationError(f"cannot write the belief file {path}: {exc}") from None
    return path if path.suffix == ".npz" else path.with_name(path.name + ".npz")


def load_belief(path):
    """Read a file written by :func:`save_belief`.

    Returns
    -------
    belief : ParticleBelief
        With its region (when saved); ``belief.info`` holds ``map_pose`` (the saved MAP
        pose), ``model`` (dict of model parameters) and any ``extra`` facts.
    contacts : Contacts or None
    """
    p = as_path(path, "path", must_exist=False)
    if not p.is_file():
        raise ValidationError(f"{path}: no such belief file (expected an .npz written by save_belief / --save)")
    try:
        z = np.load(p, allow_pickle=False)
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
        raise ValidationError(f"{path}: not a belief file (.npz): {exc}") from None
    if not hasattr(z, "files"):
        raise ValidationError(f"{path}: not a belief file: it holds one array, not an .npz archive")
    with z:
        if "poses" not in z.files or "log_weights" not in z.files:
            raise ValidationError(f"{path}: not a belief file: it has no 'poses' and 'log_weights' arrays")
        version = int(z["format_version"]) if "format_version" in z.files else 0
        if version > FORMAT_VERSION:
            raise ValidationError(f"{path}: belief file format {version} is newer than this touchloc reads "
                                  f"({FORMAT_VERSION}); upgrade touchloc")
        region = None
        if "region_center" in z.files:
            rot = z["region_rotation"]
            rot = str(rot) if rot.ndim == 0 else rot
            rho = float(z["region_rho"])
            region = PoseRegion(z["region_center"], z["region_half_extent"], rot,
                                base_rotation=z["region_base_rotation"], yaw_range=tuple(z["region_yaw_range"]),
                                rho=None if np.isnan(rho) else rho)
        meta = json.loads(str(z["meta"])) if "meta" in z.files else {}
        res = float(z["resolution"]) if "resolution" in z.files else np.nan
        info = dict(meta)
        if "map_pose" in z.files:
            info["map_pose"] = z["map_pose"]
        belief = ParticleBelief(z["poses"], z["log_weights"], region=region,
                                resolution=None if np.isnan(res) else res, info=info,
                                degenerate=bool(z["degenerate"]) if "degenerate" in z.files else False)
        contacts = None
        if "contact_points" in z.files:
            contacts = Contacts(z["contact_points"], z["contact_normals"] if "contact_normals" in z.files else None)
    return belief, contacts
