"""Superquadrics fitted to contacts (Handbook of Robotics ch. 42.2.1, eq. 42.17).

In its own frame a superquadric with extents (a, b, c) and exponents (e1, e2) is the
surface F(x) = 1 of the inside-outside function

    F(x, y, z) = ((|x|/a)^(2/e2) + (|y|/b)^(2/e2))^(e2/e1) + (|z|/c)^(2/e1)

which is the implicit form of eq. 42.17: e1, e2 near 0 give boxes, e1 = 1 with e2 near 0
... cylinders (with the book's convention e1 = 1, e2 -> 0 and our axis naming), and
e1 = e2 = 1 ellipsoids. The fit minimises, over pose, extents and exponents, the radial
distance |x| (1 - F^(-e1/2)) of every contact (a close approximation of the Euclidean
distance near the surface, Jaklic et al., "Segmentation and Recovery of Superquadrics")
divided by the position noise, plus the difference between measured normals and the
normalised gradient of F divided by the normal noise. The parameter covariance is the
inverse Gauss-Newton Hessian (J^T J)^-1 at the optimum.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from .._validate import as_count, as_float_array, as_nonnegative_float, as_points, as_pose
from ..errors import MappingError, ValidationError
from ..models import Contacts

__all__ = ["Superquadric", "fit_superquadric", "inside_outside"]

_EPS_RANGE = (0.1, 1.9)


def inside_outside(X, scale, eps):
    """F and its gradient (local frame) at local points X (M, 3)."""
    a, b, c = scale
    e1, e2 = eps
    ax, ay, az = np.abs(X[:, 0]) / a, np.abs(X[:, 1]) / b, np.abs(X[:, 2]) / c
    A = np.maximum(ax ** (2 / e2) + ay ** (2 / e2), 1e-300)
    F = A ** (e2 / e1) + az ** (2 / e1)
    k = (2 / e1) * A ** (e2 / e1 - 1)
    g = np.stack([k * ax ** (2 / e2 - 1) * np.sign(X[:, 0]) / a,
                  k * ay ** (2 / e2 - 1) * np.sign(X[:, 1]) / b,
                  (2 / e1) * az ** (2 / e1 - 1) * np.sign(X[:, 2]) / c], axis=1)
    return F, g


@dataclass
class Superquadric:
    """A fitted superquadric: pose, extents, exponents and their uncertainty.

    Attributes
    ----------
    pose : (4, 4) float
        T_world_superquadric.
    scale : (3,) float
        Extents (a, b, c) along the local axes (m).
    eps : (2,) float
        Exponents (e1, e2).
    covariance : (11, 11) float
        Covariance of (translation (3), rotation vector (3), log extents (3), e1, e2).
    rms : float
        Root-mean-square radial distance of the contacts (m).
    """

    pose: np.ndarray
    scale: np.ndarray
    eps: np.ndarray
    covariance: np.ndarray
    rms: float

    def __post_init__(self):
        self.pose = as_pose(self.pose, "pose")
        self.scale = as_float_array(self.scale, "scale", shape=(3,))
        self.eps = as_float_array(self.eps, "eps", shape=(2,))
        if np.any(self.scale <= 0) or np.any(self.eps <= 0):
            raise ValidationError(f"scale and eps must be > 0, got {self.scale.tolist()} and {self.eps.tolist()}")
        self.covariance = as_float_array(self.covariance, "covariance", shape=(11, 11))
        self.rms = as_nonnegative_float(self.rms, "rms")

    @property
    def std(self) -> dict:
        """Standard deviations: translation (m), rotation (rad), extents (m), exponents."""
        sd = np.sqrt(np.clip(np.diag(self.covariance), 0, None))
        return {"translation": sd[:3], "rotation": sd[3:6], "scale": sd[6:9] * self.scale, "eps": sd[9:11]}

    def _local(self, points):
        T = self.pose
        return (np.asarray(points, float) - T[:3, 3]) @ T[:3, :3]

    def radial_distance(self, points) -> np.ndarray:
        """(M,) approximate signed distance to the surface (negative inside, m)."""
        X = self._local(as_points(points, "points", allow_empty=True))
        F, _ = inside_outside(X, self.scale, self.eps)
        return np.linalg.norm(X, axis=1) * (1.0 - np.maximum(F, 1e-300) ** (-self.eps[0] / 2))

    def prior(self):
        """The radial distance and its gradient as a GPIS prior mean (see ShapeMap)."""
        R = self.pose[:3, :3]

        def prior(points):
            d = self.radial_distance(points)
            X = self._local(points)
            _, g = inside_outside(X, self.scale, self.eps)
            g = g @ R.T
            g /= np.maximum(np.linalg.norm(g, axis=1), 1e-12)[:, None]
            return d, g

        prior.params = {"kind": "superquadric", "scale": self.scale.tolist(), "eps": self.eps.tolist()}
        return prior

    def sample_surface(self, n: int = 2000):
        """(n, 3) world points on the surface from the parametric form (eq. 42.17).

        The points lie on a grid of about sqrt(n) by sqrt(n) parameters, so the count
        returned is the square of an integer near sqrt(n) (at least 4)."""
        m = max(2, int(np.sqrt(as_count(n, "n", max=10**7))))
        w1, w2 = np.meshgrid(np.linspace(-np.pi / 2, np.pi / 2, m), np.linspace(-np.pi, np.pi, m, endpoint=False))
        e1, e2 = self.eps

        def sp(v, e):
            return np.sign(v) * np.abs(v) ** e

        a, b, c = self.scale
        X = np.stack([a * sp(np.cos(w1), e1) * sp(np.cos(w2), e2), b * sp(np.cos(w1), e1) * sp(np.sin(w2), e2),
                      c * sp(np.sin(w1), e1)], -1).reshape(-1, 3)
        return X @ self.pose[:3, :3].T + self.pose[:3, 3]


def _unpack(x):
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(x[3:6]).as_matrix()
    T[:3, 3] = x[:3]
    return T, np.exp(x[6:9]), x[9:11]


def fit_superquadric(contacts, *, sigma_pos: float = 0.001, sigma_nor: float = 0.1, bounds=None,
                     n_starts: int = 4, rng=None) -> Superquadric:
    """Fit a superquadric (eq. 42.17) to contacts, with parameter uncertainty.

    Parameters
    ----------
    contacts : Contacts
        At least 9 contacts (world frame); normals are used when present.
    sigma_pos, sigma_nor : float
        Noise of contact positions (m) and normals.
    bounds : (lo, hi), optional
        A box that holds the object: the extents are capped at its size.
    n_starts : int
        Exponent initialisations tried (box, cylinder, ellipsoid, ...); the best fit wins.

    Returns
    -------
    Superquadric

    Raises
    ------
    ValidationError
        On bad input. MappingError: when the optimiser does not converge.
    """
    if not isinstance(contacts, Contacts):
        raise ValidationError(f"contacts must be a touchloc.models.Contacts, got {type(contacts).__name__}")
    if len(contacts) < 9:
        raise ValidationError(f"a superquadric has 11 parameters: give at least 9 contacts, got {len(contacts)}")
    for name, v in (("sigma_pos", sigma_pos), ("sigma_nor", sigma_nor)):
        if isinstance(v, bool) or not isinstance(v, (int, float, np.floating)) or not (np.isfinite(v) and v > 0):
            raise ValidationError(f"{name} must be a positive finite number, got {v!r}")
    if isinstance(n_starts, bool) or not isinstance(n_starts, (int, np.integer)) or not 1 <= n_starts <= 16:
        raise ValidationError(f"n_starts must be an integer in [1, 16], got {n_starts!r}")
    P = contacts.points
    N = contacts.normals
    ctr = P.mean(axis=0)
    C = np.cov((P - ctr).T) + 1e-12 * np.eye(3)
    w, V = np.linalg.eigh(C)
    if np.linalg.det(V) < 0:
        V[:, 0] *= -1
    ext = np.abs((P - ctr) @ V).max(axis=0)
    if bounds is not None:
        from .shape_map import as_bounds

        bounds = as_bounds(bounds)
    cap = np.inf if bounds is None else float(np.max(np.asarray(bounds[1]) - np.asarray(bounds[0])))
    ext = np.clip(ext, 1e-3, cap)
    rv0 = Rotation.from_matrix(V).as_rotvec()
    hi_log = np.log(cap) if np.isfinite(cap) else np.log(10.0)

    def residuals(x):
        T, s, e = _unpack(x)
        X = (P - T[:3, 3]) @ T[:3, :3]
        F, g = inside_outside(X, s, e)
        r = np.linalg.norm(X, axis=1) * (1.0 - np.maximum(F, 1e-300) ** (-e[0] / 2)) / sigma_pos
        if N is None:
            return r
        gw = g @ T[:3, :3].T
        gw /= np.maximum(np.linalg.norm(gw, axis=1), 1e-12)[:, None]
        return np.concatenate([r, ((gw - N) / sigma_nor).reshape(-1)])

    starts = [(0.3, 0.3), (1.0, 1.0), (0.3, 1.0), (1.0, 0.3), (0.6, 0.6), (0.2, 1.5)][:n_starts]
    lb = np.r_[np.full(6, -np.inf), np.full(3, np.log(1e-4)), _EPS_RANGE[0], _EPS_RANGE[0]]
    ub = np.r_[np.full(6, np.inf), np.full(3, hi_log), _EPS_RANGE[1], _EPS_RANGE[1]]
    best = None
    for e in starts:
        x0 = np.r_[ctr, rv0, np.log(ext), e]
        x0 = np.clip(x0, lb + 1e-9, ub - 1e-9)
        try:
            with np.errstate(all="ignore"):
                sol = least_squares(residuals, x0, bounds=(lb, ub), x_scale="jac", max_nfev=200)
        except (ValueError, np.linalg.LinAlgError):
            continue
        if np.all(np.isfinite(sol.fun)) and (best is None or sol.cost < best.cost):
            best = sol
    if best is None:
        raise MappingError("the superquadric fit did not converge")
    J = best.jac
    cov = np.linalg.pinv(J.T @ J)
    T, s, e = _unpack(best.x)
    X = (P - T[:3, 3]) @ T[:3, :3]
    F, _ = inside_outside(X, s, e)
    rad = np.linalg.norm(X, axis=1) * (1.0 - np.maximum(F, 1e-300) ** (-e[0] / 2))
    return Superquadric(T, s, np.asarray(e, float), cov, float(np.sqrt(np.mean(rad**2))))
