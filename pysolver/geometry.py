"""Frames and rotations: the one place where sign conventions live.

* :func:`print_transform` maps the flat shell frame to the print frame of a
  layer (``docs/design-folder.md``, "Print frame").
* :func:`rotvec_to_matrix` / :func:`matrix_to_rotvec` convert rotation vectors
  (angle-axis, rad) to matrices and back (Rodrigues, Supplementary Eq. 1).
* :func:`frames_to_rotation` is the "two orthonormal frames" rotation used to
  orient every base: it maps a direction pair (axis, side) of one frame onto
  the pair of another frame (the reference's ``vectors2rotation``).
* :func:`flat_to_target` / :func:`target_to_flat` apply a base's rigid pose.

All rotations act on column vectors: ``p' = R @ p``.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from .errors import InputError
from .params import UNIT_CELL, layer_sign


def print_transform(layer, layer_h: float = UNIT_CELL.layer_h) -> np.ndarray:
    """4x4 homogeneous transform from the flat shell frame to a layer's print frame.

    The print bed is z = 0 with the far face (brackets) down.  Bottom layer:
    ``(x, y, z + layer_h)``; top layer, turned over about x: ``(x, -y, layer_h - z)``.

    Parameters
    ----------
    layer : {"top", "bottom", 0, 1}
        Layer name or index (0 = top, 1 = bottom).
    layer_h : float, mm
        Layer height (base_th + base_p = 2.3 mm).

    Returns
    -------
    T : (4, 4) float
        Apply as ``(T @ [x, y, z, 1])[:3]``.
    """
    s = layer_sign(layer)
    T = np.eye(4)
    if s > 0:
        T[1, 1] = -1.0
        T[2, 2] = -1.0
    T[2, 3] = layer_h
    return T


def apply_transform(T: np.ndarray, P: np.ndarray) -> np.ndarray:
    """Apply a 4x4 transform to points ``P : (n, 3)``; returns ``(n, 3)``."""
    P = np.asarray(P, dtype=float)
    return P @ T[:3, :3].T + T[:3, 3]


def rotvec_to_matrix(r: np.ndarray) -> np.ndarray:
    """Rotation matrices from rotation vectors.

    Parameters
    ----------
    r : (3,) or (n, 3) float, rad
        Rotation vector: axis * angle (right-hand rule).

    Returns
    -------
    R : (3, 3) or (n, 3, 3) float
    """
    r = np.asarray(r, dtype=float)
    return Rotation.from_rotvec(r).as_matrix()


def matrix_to_rotvec(R: np.ndarray) -> np.ndarray:
    """Rotation vectors (rad) from rotation matrices ``(3, 3)`` or ``(n, 3, 3)``."""
    return Rotation.from_matrix(np.asarray(R, dtype=float)).as_rotvec()


def _unit(v: np.ndarray, what: str) -> np.ndarray:
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    if np.any(n < 1e-12):
        raise InputError(f"frames_to_rotation: zero-length {what} vector",
                         fix="check for degenerate faces or coincident face centres")
    return v / n


def frames_to_rotation(axis_from, side_from, axis_to, side_to) -> np.ndarray:
    """Rotation taking the frame (axis_from, side_from) onto (axis_to, side_to).

    Each frame is made orthonormal: ``a = axis/|axis|``, ``b`` = side with its
    ``a`` component removed, ``c = a x b``.  Then ``R = [a' b' c'] [a b c]^T``,
    so ``R a = a'`` exactly and ``R b = b'`` (sides after orthogonalisation).

    Parameters
    ----------
    axis_from, side_from, axis_to, side_to : (3,) or (n, 3) float

    Returns
    -------
    R : (3, 3) or (n, 3, 3) float, rotation matrices (det +1)
    """
    args = [np.atleast_2d(np.asarray(x, dtype=float)) for x in
            (axis_from, side_from, axis_to, side_to)]
    single = np.ndim(axis_from) == 1

    def frame(ax, sd):
        a = _unit(ax, "axis")
        b = sd - np.sum(sd * a, axis=1, keepdims=True) * a
        b = _unit(b, "side (parallel to the axis)")
        c = np.cross(a, b)
        return np.stack([a, b, c], axis=2)  # columns a, b, c

    A = frame(args[0], args[1])
    B = frame(args[2], args[3])
    R = B @ np.transpose(A, (0, 2, 1))
    return R[0] if single else R


def flat_to_target(P_flat, R, c_target, c_flat) -> np.ndarray:
    """Map points of a base from the flat shell frame to the target frame.

    ``p_target = c_target + R (p_flat - (x_flat, y_flat, 0))``.

    Parameters
    ----------
    P_flat : (n, 3) float, mm
    R : (3, 3) float
    c_target : (3,) float, mm
        Target face centroid.
    c_flat : (2,) float, mm
        Flat face centroid.
    """
    c0 = np.array([c_flat[0], c_flat[1], 0.0])
    return (np.asarray(P_flat, float) - c0) @ np.asarray(R).T + np.asarray(c_target, float)


def target_to_flat(P_target, R, c_target, c_flat) -> np.ndarray:
    """Inverse of :func:`flat_to_target`: ``p_flat = R^T (p_target - c_target) + (x, y, 0)``."""
    c0 = np.array([c_flat[0], c_flat[1], 0.0])
    return (np.asarray(P_target, float) - np.asarray(c_target, float)) @ np.asarray(R) + c0


__all__ = ["print_transform", "apply_transform", "rotvec_to_matrix", "matrix_to_rotvec",
           "frames_to_rotation", "flat_to_target", "target_to_flat"]
