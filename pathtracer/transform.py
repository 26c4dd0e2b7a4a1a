"""4x4 affine transforms with Mitsuba 3's conventions (float64 numpy, column vectors: p' = M @ p).

The free functions build one operation each; :class:`Transform` chains them the way
``mi.ScalarTransform4f`` does: ``Transform().translate(t).rotate(a, 30).scale(2)`` is
``T @ R @ S``, so the operation written last applies to points first.
(A Mitsuba XML ``<transform>`` lists its operations the other way round: each one
left-multiplies, ``M = op @ M``; see :func:`pathtracer.loader_xml`.)
"""

from __future__ import annotations

import numpy as np

_UNIT_AXIS_TOL = 1e-6


def _vec3(v, default: float = 0.0) -> np.ndarray:
    """A float64 3-vector from a scalar (replicated) or a 3-sequence."""
    a = np.asarray(v, dtype=np.float64).reshape(-1)
    if a.size == 1:
        return np.full(3, a[0])
    if a.size != 3:
        raise ValueError(f"expected 1 or 3 numbers, got {a.size}")
    return a


def translate(v) -> np.ndarray:
    """Translation by ``v`` (3 numbers, or one number for all axes)."""
    m = np.eye(4)
    m[:3, 3] = _vec3(v)
    return m


def scale(v) -> np.ndarray:
    """Scaling by ``v`` (one number, uniform, or 3 numbers)."""
    return np.diag(np.append(_vec3(v), 1.0))


def rotate(axis, angle_deg: float) -> np.ndarray:
    """Right-handed rotation by ``angle_deg`` degrees about ``axis`` (Rodrigues' formula).

    ``axis`` must be a unit vector: Mitsuba 3 does not normalize it (``rotate([0, 2, 0], 30)``
    there is not a rotation), so a non-unit axis is refused rather than given a second meaning.
    """
    a = _vec3(axis)
    n = float(np.linalg.norm(a))
    if not abs(n - 1.0) <= _UNIT_AXIS_TOL:
        raise ValueError(f"rotation axis ({a[0]:g}, {a[1]:g}, {a[2]:g}) must be a unit vector (length {n:g})")
    t = np.radians(float(angle_deg))
    c, s = np.cos(t), np.sin(t)
    x, y, z = a
    k = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    m = np.eye(4)
    m[:3, :3] = c * np.eye(3) + s * k + (1.0 - c) * np.outer(a, a)
    return m


def coordinate_system(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors completing unit ``n`` to an orthonormal basis (Mitsuba's ``coordinate_system``)."""
    x, y, z = n
    sign = np.copysign(1.0, z)
    a = -1.0 / (sign + z)
    b = x * y * a
    s = np.array([1.0 + sign * x * x * a, sign * b, -sign * x])
    t = np.array([b, sign + y * y * a, -y])
    return s, t


def look_at(origin, target, up=None) -> np.ndarray:
    """Mitsuba's ``look_at``: local +z looks from ``origin`` to ``target``, local +x is the image's left.

    Columns: [left, new_up, dir, origin] with dir = normalize(target - origin),
    left = normalize(up x dir), new_up = dir x left. With no ``up`` (or a zero one) one is
    chosen as Mitsuba does. Raises ValueError when origin == target or up is parallel to dir.
    """
    origin, target = _vec3(origin), _vec3(target)
    d = target - origin
    dn = np.linalg.norm(d)
    if not dn > 0:
        raise ValueError("lookat origin and target coincide")
    d = d / dn
    up = np.zeros(3) if up is None else _vec3(up)
    if not np.any(up):
        up, _ = coordinate_system(d)
    left = np.cross(up, d)
    ln = np.linalg.norm(left)
    if not ln > 1e-12 * max(1.0, float(np.linalg.norm(up))):
        raise ValueError("lookat up vector is zero or parallel to the viewing direction")
    left = left / ln
    new_up = np.cross(d, left)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = left, new_up, d, origin
    return m


def normal_matrix(m: np.ndarray) -> np.ndarray:
    """The 3x3 matrix that transforms normals under ``m``: inverse transpose of its linear part."""
    return np.linalg.inv(np.asarray(m, dtype=np.float64)[:3, :3]).T


def transform_points(m: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Apply affine ``m`` to points ``p`` of shape (..., 3)."""
    out = np.asarray(p, dtype=np.float64) @ m[:3, :3].T
    out += m[:3, 3]  # (in place: one array of a big mesh's size, not two)
    return out


def transform_vectors(m: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Apply the linear part of ``m`` to vectors ``v`` of shape (..., 3)."""
    return np.asarray(v, dtype=np.float64) @ m[:3, :3].T


def transform_normals(m: np.ndarray, n: np.ndarray) -> np.ndarray:
    """Transform normals ``n`` (..., 3) with the inverse transpose of ``m`` and normalize them."""
    out = np.asarray(n, dtype=np.float64) @ normal_matrix(m).T
    out /= np.linalg.norm(out, axis=-1, keepdims=True)
    return out


class Transform:
    """An affine transform; chaining right-multiplies, like ``mi.ScalarTransform4f``.

    ``matrix`` is the 4x4 float64 array; ``load_dict`` accepts a Transform wherever Mitsuba
    takes a ``to_world``.
    """

    def __init__(self, matrix=None):
        self.matrix = np.eye(4) if matrix is None else np.array(matrix, dtype=np.float64).reshape(4, 4)

    def __matmul__(self, other: Transform) -> Transform:
        return Transform(self.matrix @ other.matrix)

    def translate(self, v) -> Transform:
        return Transform(self.matrix @ translate(v))

    def scale(self, v) -> Transform:
        return Transform(self.matrix @ scale(v))

    def rotate(self, axis, angle: float) -> Transform:
        return Transform(self.matrix @ rotate(axis, angle))

    def look_at(self, origin, target, up=None) -> Transform:
        return Transform(self.matrix @ look_at(origin, target, up))

    def inverse(self) -> Transform:
        return Transform(np.linalg.inv(self.matrix))

    def __repr__(self) -> str:
        return f"Transform({self.matrix.tolist()!r})"
