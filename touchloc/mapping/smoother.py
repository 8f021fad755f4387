"""Trajectory smoothing for tactile SLAM: revise every pose at once from the surface itself.

A filter fixes each pose when its touches arrive and folds them into the map there. Early
on the map is a few contacts and a prior blob, touches land on parts not yet touched,
and a pose error of a few millimetres made then is frozen into the map; later poses
register consistently to the distorted map and the error never goes away. The smoother
revises all poses together, so that touches made later correct the early ones.

Its cost function has two kinds of terms:

- *surface consistency*: two contacts i, j made at different steps that lie within a
  radius of each other on the object, with normals that agree, must lie on one smooth
  surface. Their residual is the symmetric point-to-plane distance
  n_ij . (x_j - x_i), with n_ij the normalised sum of their normals (Rusinkiewicz, "A
  symmetric objective function for ICP", SIGGRAPH 2019): zero for any two points on a
  plane, a sphere or a cylinder's cross-section, so curved objects need no special case.
  Its variance is 2 sigma_pos^2 + |x_j - x_i|^2 sigma_nor^2 / 2 (the normals' noise
  tilts the plane);
- *motion*: each pose follows its predecessor by the odometry (identity when there is
  none), with the motion noise of the filter.

x = T_s^-1 p is a contact's object-frame point at its step's pose T_s. Poses are
corrected by a world-frame rotation phi about the object's origin and a translation
rho; the Jacobians are dx/drho = -R^T, dx/dphi = R^T [p - t]_x and, for the normals,
dn/dphi = R^T [n]_x (without the normals' part, rotating every pose together, which
leaves every residual unchanged, would look like a descent direction and the solution
would drift in yaw). Gauss-Newton with a Cauchy loss (iteratively reweighted), the
neighbour pairs found again at every iteration; the first pose is held (it fixes the
map's frame). A result whose robust cost is higher than the start's is refused.
"""

from __future__ import annotations

import numpy as np
from scipy import sparse
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from ..geometry import checked_rotations

__all__ = ["smooth_trajectory"]


def _skew(v):
    o = np.zeros(v.shape[:-1] + (3, 3))
    o[..., 0, 1], o[..., 0, 2] = -v[..., 2], v[..., 1]
    o[..., 1, 0], o[..., 1, 2] = v[..., 2], -v[..., 0]
    o[..., 2, 0], o[..., 2, 1] = -v[..., 1], v[..., 0]
    return o


def smooth_trajectory(poses, anchor, points, normals, owner, motions, *, planar: bool, sigma_pos: float,
                      sigma_nor: float, radius: float, neighbours: int = 10, loss_scale: float = 3.0,
                      iterations: int = 6, hold: int = 0, fixed_turns=None):
    """Revise a trajectory of object poses from its contacts and motion model.

    Internal to :class:`touchloc.mapping.TactileSLAM` (inputs are trusted).

    Parameters
    ----------
    poses : (S, 4, 4) float
        Current estimates T_world_object, one per step.
    anchor : (4, 4) float
        The pose before the first step (held fixed).
    points, normals : (K, 3) float
        Contacts, world frame.
    owner : (K,) int
        The step each contact was made at.
    motions : list of S (D (4, 4), (sigma_t, sigma_r)) or None
        Step s's motion model: T_s = D T_{s-1} up to noise of that standard deviation
        (T_{-1} = anchor); None holds the step fixed (no motion before it).
    planar : bool
        Corrections in x, y and yaw only.
    radius : float
        Contacts closer than this (object frame) are compared.
    neighbours : int
        At most this many partners per contact.
    loss_scale : float
        Cauchy scale, in standard deviations of a pair's residual.
    iterations : int
    hold : int
        The first ``hold`` steps keep their poses (a fixed-lag smoother: old poses, long
        settled, anchor the rest and are not solved for again).
    fixed_turns : list of S bool, optional
        Steps whose turn about their motion's axis stays as it is: the revision may move
        such a pose in every other way, but not turn it about the axis of the rotation
        its motion ``D`` makes (through that rotation's fixed point). For an object a hand
        turns, the steps whose contacts did not show the turn (a mug's body: the filter
        set those turns from the odometry alone, and the surface pairs and the motion
        factors would drag them back towards the odometry's bias).

    Returns
    -------
    poses : (S, 4, 4) float
    info : dict
        ``pairs`` (pairs in the last iteration), ``iterations``, ``cost`` (start, end),
        ``accepted``.
    """
    T = np.array(poses, dtype=float, copy=True)
    S = len(T)
    dof = np.array([0, 1, 5]) if planar else np.arange(6)
    d = len(dof)
    free = np.array([m is not None for m in motions])
    free[:hold] = False
    col = np.full(S, -1)
    col[free] = np.arange(int(free.sum()))
    n_par = int(free.sum()) * d
    info = dict(pairs=0, iterations=0, cost=(0.0, 0.0), accepted=False)
    if n_par == 0 or len(points) < 2:
        return T, info
    P, N, own = np.asarray(points, float), np.asarray(normals, float), np.asarray(owner, np.int64)
    Dm = np.array([np.eye(4) if m is None else m[0] for m in motions])
    sigm = np.array([[1.0] * 6 if m is None else [m[1][0]] * 3 + [m[1][1]] * 3 for m in motions])

    turn_rows, turn_axes, turn_pts = [], [], []
    if fixed_turns is not None:
        fixed = np.flatnonzero(np.asarray(fixed_turns, bool) & free)
        # the motions' rotation vectors in one call (one call per step cost 0.2 ms each)
        W = checked_rotations(Dm[fixed, :3, :3]).as_rotvec() if len(fixed) else np.zeros((0, 3))
        for k, w in zip(fixed, W):
            th = float(np.linalg.norm(w))
            if th < 1e-9:
                continue
            turn_rows.append(k)
            turn_axes.append(w / th)
            turn_pts.append(np.linalg.lstsq(np.eye(3) - Dm[k, :3, :3], Dm[k, :3, 3], rcond=None)[0])
    turn_rows = np.array(turn_rows, dtype=np.int64)
    turn_axes, turn_pts = np.array(turn_axes).reshape(-1, 3), np.array(turn_pts).reshape(-1, 3)

    def associate(T):
        """Neighbour pairs i < j from different steps with agreeing normals (object frame)."""
        R, t = T[own, :3, :3], T[own, :3, 3]
        X = np.einsum("kji,kj->ki", R, P - t)
        Nl = np.einsum("kji,kj->ki", R, N)
        k = min(len(X), 3 * neighbours + 1)
        dist, idx = cKDTree(X).query(X, k=k, distance_upper_bound=radius)
        I = np.repeat(np.arange(len(X)), k).reshape(len(X), k)
        ok = np.isfinite(dist) & (idx < len(X))
        J = np.where(ok, idx, 0)
        ok &= (J > I) & (own[J] != own[I]) & (np.einsum("ki,kmi->km", Nl, Nl[J]) > np.cos(np.deg2rad(30.0)))
        ok &= np.cumsum(ok, axis=1) <= neighbours
        return I[ok], J[ok]

    def linearise(T, I, J):
        """Whitened residuals z and their Jacobian A (sparse); the first m0 rows are pairs."""
        R, t = T[own, :3, :3], T[own, :3, 3]
        X = np.einsum("kji,kj->ki", R, P - t)
        Nl = np.einsum("kji,kj->ki", R, N)
        rows, cols, vals, res = [], [], [], []
        if len(I):
            ns = Nl[I] + Nl[J]
            nn = np.linalg.norm(ns, axis=1)
            nh = ns / nn[:, None]
            dX = X[J] - X[I]
            sd = np.sqrt(2 * sigma_pos**2 + 0.5 * np.einsum("ki,ki->k", dX, dX) * sigma_nor**2)
            res.append(np.einsum("ki,ki->k", nh, dX) / sd)
            u = dX / nn[:, None]
            for sgn, K in ((-1.0, I), (1.0, J)):
                Rk = R[K]
                Jx = np.concatenate([-np.transpose(Rk, (0, 2, 1)), np.einsum("kji,kjl->kil", Rk, _skew(P[K] - t[K]))], 2)
                Jn = np.concatenate([np.zeros((len(K), 3, 3)), np.einsum("kji,kjl->kil", Rk, _skew(N[K]))], 2)
                Jr = (sgn * np.einsum("ki,kij->kj", nh, Jx) + np.einsum("ki,kij->kj", u, Jn))[:, dof]
                c = col[own[K]]
                keep = c >= 0
                rows.append(np.repeat(np.flatnonzero(keep), d))
                cols.append((c[keep, None] * d + np.arange(d)).ravel())
                vals.append((Jr[keep] / sd[keep, None]).ravel())
        m0 = len(I)
        # motion factors: T_s = D T_{s-1}, residual (t_s - R_D t_{s-1} - t_D, rotvec(R_s R_{s-1}^T R_D^T))
        prev = np.concatenate([anchor[None], T[:-1]])
        fs = np.flatnonzero(free)
        RD, tD = Dm[fs, :3, :3], Dm[fs, :3, 3]
        et = T[fs, :3, 3] - (np.einsum("sij,sj->si", RD, prev[fs, :3, 3]) + tD)
        er = checked_rotations(T[fs, :3, :3] @ np.transpose(prev[fs, :3, :3], (0, 2, 1))
                                  @ np.transpose(RD, (0, 2, 1))).as_rotvec()
        sig = sigm[fs][:, dof]                                              # (F, d)
        res.append((np.concatenate([et, er], 1)[:, dof] / sig).ravel())
        r_idx = m0 + np.arange(len(fs) * d).reshape(-1, d)                  # (F, d)
        rows.append(r_idx.ravel())
        cols.append((col[fs, None] * d + np.arange(d)).ravel())
        vals.append((1.0 / sig).ravel())
        chain = (fs > 0) & free[np.maximum(fs - 1, 0)]                      # predecessor solved for too
        if np.any(chain):
            B = np.zeros((int(chain.sum()), 6, 6))
            B[:, :3, :3] = B[:, 3:, 3:] = -RD[chain]
            B = B[:, dof][:, :, dof] / sig[chain][:, :, None]
            rows.append(np.repeat(r_idx[chain], d, axis=1).ravel())
            cols.append(np.tile(col[fs[chain] - 1, None] * d + np.arange(d), (1, d)).ravel())
            vals.append(B.ravel())
        mrow = m0 + len(fs) * d
        if len(turn_rows):
            # the increment along each fixed step's turn is held at zero
            k = len(turn_rows)
            rows.append(np.repeat(mrow + np.arange(k), d))
            cols.append((col[turn_rows, None] * d + np.arange(d)).ravel())
            U = np.concatenate([np.cross(turn_axes, T[turn_rows, :3, 3] - turn_pts), turn_axes], 1)[:, dof]
            vals.append((U / 1e-6).ravel())
            res.append(np.zeros(k))
            mrow += k
        A = sparse.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                              shape=(mrow, n_par))
        return A, np.concatenate(res), m0

    def robust(z, m0):
        c2 = loss_scale**2
        return float(0.5 * c2 * np.sum(np.log1p(z[:m0] ** 2 / c2)) + 0.5 * np.sum(z[m0:] ** 2))

    T0 = T.copy()
    for it in range(iterations):
        A, z, m0 = linearise(T, *associate(T))
        w = np.ones(len(z))
        w[:m0] = 1.0 / (1.0 + z[:m0] ** 2 / loss_scale**2)      # Cauchy, iteratively reweighted
        Aw = A.multiply(w[:, None]).tocsr()
        H = (A.T @ Aw).toarray() + 1e-9 * np.eye(n_par)
        g = Aw.T @ z
        try:
            delta = -np.linalg.solve(H, g)
        except np.linalg.LinAlgError:
            break
        full = np.zeros((S, 6))
        full[np.flatnonzero(free)[:, None], dof[None, :]] = delta.reshape(-1, d)
        T[:, :3, :3] = Rotation.from_rotvec(full[:, 3:]).as_matrix() @ T[:, :3, :3]
        T[:, :3, 3] += full[:, :3]
        info["iterations"] = it + 1
        if np.max(np.abs(delta)) < 1e-6:
            break
    # accept only a lower robust cost, both scored on the pairs of the result
    I, J = associate(T)
    cost = [robust(*linearise(X, I, J)[1:]) for X in (T0, T)]
    info.update(pairs=len(I), cost=tuple(cost), accepted=cost[1] <= cost[0])
    return (T if info["accepted"] else T0), info
