"""Camera rays through jittered sub-pixel positions."""

import warp as wp

from kernels.sampling import square_to_disk_concentric
from kernels.types import CameraData, Ray


@wp.func
def camera_ray(cam: CameraData, col: int, row: int, jx: float, jy: float) -> Ray:
    """Ray through film point (col + jx, row + jy); row 0 is the top. Starts on the near plane, ends at far_clip.

    Same mapping as the seed (alpha, beta = tan(fov/2) (2 (i + x) / W - 1), tan(fov/2) (1 - 2 (j + y) / H)),
    written in Mitsuba's camera frame where local +x is image left.
    """
    fx = (float(col) + jx) / float(cam.width)
    fy = (float(row) + jy) / float(cam.height)
    local = wp.normalize(wp.vec3((1.0 - 2.0 * fx) * cam.tan_x, (1.0 - 2.0 * fy) * cam.tan_y, 1.0))
    inv_z = 1.0 / local[2]
    near_t = cam.near_clip * inv_z
    r = Ray()
    r.d = wp.normalize(cam.to_world * local)
    r.o = cam.origin + near_t * r.d
    r.tmax = cam.far_clip * inv_z - near_t
    return r


@wp.func
def thin_lens_ray(cam: CameraData, col: int, row: int, jx: float, jy: float, a1: float, a2: float) -> Ray:
    """Mitsuba's ``thinlens``: from a point on the lens disk (radius cam.aperture_radius, drawn with the concentric
    map from ``a1, a2``) through the point the pinhole ray would reach at depth cam.focus_distance. Starts on the near
    plane, ends at far_clip (both measured along local z, as the pinhole)."""
    fx = (float(col) + jx) / float(cam.width)
    fy = (float(row) + jy) / float(cam.height)
    focus = cam.focus_distance * wp.vec3((1.0 - 2.0 * fx) * cam.tan_x, (1.0 - 2.0 * fy) * cam.tan_y, 1.0)
    disk = cam.aperture_radius * square_to_disk_concentric(a1, a2)
    lens = wp.vec3(disk[0], disk[1], 0.0)
    local = wp.normalize(focus - lens)
    inv_z = 1.0 / local[2]
    r = Ray()
    r.d = wp.normalize(cam.to_world * local)
    r.o = cam.origin + cam.to_world * lens + (cam.near_clip * inv_z) * r.d
    r.tmax = (cam.far_clip - cam.near_clip) * inv_z
    return r
