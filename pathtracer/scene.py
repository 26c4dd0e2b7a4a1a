"""The scene model: plain data that loaders produce and the driver uploads.

Everything here is in world space, float64 numpy, already validated. Data flows one way:
file or dict -> ``Scene`` -> device arrays (``pathtracer.device_scene``) -> kernels.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

DIFFUSE = 0
MIRROR = 1  # Mitsuba's conductor with material "none": reflectance 1 at every angle
DIELECTRIC = 2
THIN_DIELECTRIC = 3
CONDUCTOR = 4  # smooth, with a complex index of refraction
PLASTIC = 5
ROUGH_CONDUCTOR = 6
ROUGH_PLASTIC = 7
MATERIAL_KINDS = {"diffuse": DIFFUSE, "mirror": MIRROR, "dielectric": DIELECTRIC, "thindielectric": THIN_DIELECTRIC,
                  "conductor": CONDUCTOR, "plastic": PLASTIC, "roughconductor": ROUGH_CONDUCTOR,
                  "roughplastic": ROUGH_PLASTIC}
DELTA_KINDS = ("mirror", "dielectric", "thindielectric", "conductor")  # no lobe that next-event estimation sees


@dataclass(frozen=True)
class Material:
    """A BSDF, as Mitsuba's plugin of the same name (docs/mitsuba_semantics/study_bsdfs.md):

    - ``diffuse``: Lambertian, albedo ``rgb``;
    - ``mirror``: perfect reflection scaled by ``rgb`` (Mitsuba's conductor with material "none");
    - ``dielectric`` / ``thindielectric``: smooth glass of relative index ``eta[0]`` (interior over exterior),
      ``rgb`` scaling reflection and ``rgb2`` transmission; two-sided by nature;
    - ``conductor`` / ``roughconductor``: complex index ``eta + i k`` per channel, ``rgb`` the
      specular_reflectance; the rough one with microfacet ``distribution`` of roughness ``alpha``;
    - ``plastic``: a diffuse base ``rgb`` under a smooth dielectric coat of index ``eta[0]``, whose reflection
      ``rgb2`` scales; ``roughplastic`` the same under a rough coat (``distribution``, ``alpha``).

    One-sided materials reflect only on their front side (Mitsuba: the shading normal's side; the loader winds
    rectangles and cubes so that the face normal agrees); ``twosided`` ones on both.
    """

    kind: str
    rgb: tuple[float, float, float]
    twosided: bool = False
    rgb2: tuple[float, float, float] = (1.0, 1.0, 1.0)
    eta: tuple[float, float, float] = (1.0, 1.0, 1.0)
    k: tuple[float, float, float] = (0.0, 0.0, 0.0)
    alpha: float = 0.0
    distribution: str = "beckmann"
    nonlinear: bool = False
    texture: int = -1  # >= 0: Scene.textures[texture] gives ``rgb`` per point (``rgb`` is then its mean)
    # the bsdf's id: names its parameters (pathtracer/gradients.py); not part of equality (it changes nothing in
    # the image), but Scene.add_material keeps bsdfs of different ids apart, so that each has its own gradient
    name: str = field(default="", compare=False)

    @property
    def code(self) -> int:
        return MATERIAL_KINDS[self.kind]

    @property
    def is_twosided(self) -> bool:
        """Does it scatter light arriving on either side (glass always does)?"""
        return self.twosided or self.kind in ("dielectric", "thindielectric")

    @property
    def specular_sampling_weight(self) -> float:
        """Plastic's probability scale for picking the coat's reflection (Mitsuba: s_mean / (d_mean + s_mean))."""
        s = sum(self.rgb2) / 3.0
        return s / (sum(self.rgb) / 3.0 + s)

    @property
    def fdr_int(self) -> float:
        """Plastic's internal diffuse Fresnel reflectance, Mitsuba's fresnel_diffuse_reflectance(1 / eta)."""
        return fresnel_diffuse_reflectance(1.0 / self.eta[0])


def fresnel_diffuse_reflectance(eta: float) -> float:
    """Hemispherical average of a dielectric's Fresnel reflectance, Mitsuba's fits (Egan and Hilgeman below 1,
    d'Eon and Irving above)."""
    inv = 1.0 / eta
    if eta < 1.0:
        return 0.0636 * inv + eta * (eta * -1.4399 + 0.7099) + 0.6681
    c = (0.919317, -3.4793, 6.75335, -7.80989, 4.98554, -1.36881)
    return sum(ci * inv**i for i, ci in enumerate(c))


DEFAULT_MATERIAL = Material("diffuse", (0.5, 0.5, 0.5))  # Mitsuba's bsdf for a shape that names none


@dataclass(frozen=True)
class PixelFilter:
    """A film's reconstruction filter, as Mitsuba's separable rfilters: the pixel's value is the filter-weighted
    mean of the radiance over the film around its centre (weight f(dx) f(dy), dx, dy in pixels), truncated at the
    film's edges (Mitsuba drops splats that fall outside the film).

    ``box``: f = 1 on [-0.5, 0.5) (each sample counts in its own pixel). ``tent``: max(0, 1 - |x| / radius).
    ``gaussian``: max(0, exp(-x^2 / (2 stddev^2)) - exp(-radius^2 / (2 stddev^2))), radius = 4 stddev.
    """

    kind: str = "box"
    radius: float = 0.5
    stddev: float = 0.5  # gaussian only

    @staticmethod
    def gaussian(stddev: float = 0.5) -> "PixelFilter":
        return PixelFilter("gaussian", 4.0 * stddev, stddev)

    @property
    def is_box(self) -> bool:
        return self.kind == "box"

    def eval(self, x) -> np.ndarray:
        """f(x), x in pixels."""
        x = np.asarray(x, dtype=np.float64)
        if self.kind == "box":
            return ((x >= -0.5) & (x < 0.5)).astype(np.float64)
        if self.kind == "tent":
            return np.maximum(0.0, 1.0 - np.abs(x) / self.radius)
        a = -1.0 / (2.0 * self.stddev**2)
        return np.maximum(0.0, np.exp(a * x * x) - np.exp(a * self.radius**2))


@dataclass
class Camera:
    """A pinhole camera as Mitsuba's ``perspective`` sensor (or its ``thinlens``, with an aperture): looks along
    local +z, local +x is image left.

    ``fov`` is in degrees along ``fov_axis`` (``x``, ``y``, ``diagonal``, ``smaller`` or ``larger``).
    """

    to_world: np.ndarray  # 4x4
    fov: float
    fov_axis: str = "x"
    near_clip: float = 1e-2
    far_clip: float = 1e4
    aperture_radius: float = 0.0  # > 0: Mitsuba's thinlens (a lens disk of this radius, in focus at focus_distance)
    focus_distance: float = 1e4

    def tan_half_fov(self, width: int, height: int) -> tuple[float, float]:
        """tan of the half field of view along image x and y."""
        t = float(np.tan(np.radians(self.fov) / 2.0))
        aspect = width / height
        axis = self.fov_axis
        if axis == "smaller":
            axis = "x" if width <= height else "y"
        elif axis == "larger":
            axis = "x" if width >= height else "y"
        if axis == "x":
            return t, t / aspect
        if axis == "y":
            return t * aspect, t
        # diagonal
        diag = np.hypot(width, height)
        return t * width / diag, t * height / diag


@dataclass
class Sphere:
    center: np.ndarray  # (3,)
    radius: float
    material: int  # index into Scene.materials
    rotation: np.ndarray | None = None  # 3x3: the object frame (for texture coordinates), None: the world's


@dataclass
class Texture:
    """Mitsuba's ``checkerboard`` (``color0`` where the two uv cells' parities agree, else ``color1``) or
    ``bitmap`` (linear RGB ``image``, row 0 at v = 0, ``filter`` bilinear or nearest, ``wrap`` repeat, mirror or
    clamp), looked up at ``to_uv`` (2x3 affine) times the surface's uv."""

    kind: str
    to_uv: np.ndarray = field(default_factory=lambda: np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]))
    color0: tuple[float, float, float] = (0.4, 0.4, 0.4)
    color1: tuple[float, float, float] = (0.2, 0.2, 0.2)
    image: np.ndarray | None = None
    filter: str = "bilinear"
    wrap: str = "repeat"
    filename: str = ""

    def mean(self) -> tuple[float, float, float]:
        if self.kind == "checkerboard":
            return tuple(0.5 * (a + b) for a, b in zip(self.color0, self.color1))
        return tuple(float(x) for x in self.image.reshape(-1, 3).mean(axis=0))


@dataclass
class TriangleMesh:
    """Triangles in world space. ``normals`` are per-vertex shading normals, or None for flat shading.

    ``light`` is the index of the area light this mesh emits as (a rectangle), or -1.
    ``shape`` says what the triangles stand for: "rectangle" (2 triangles: one parallelogram), "cube" (12: six
    parallelograms, two triangles each) or "mesh"; rectangles and cubes are rendered as analytic quads.
    """

    vertices: np.ndarray  # (N, 3) float64
    faces: np.ndarray  # (M, 3) int64, counter-clockwise seen from the front
    normals: np.ndarray | None
    material: int
    light: int = -1
    name: str = ""
    shape: str = "mesh"
    uvs: np.ndarray | None = None  # (N, 2) texture coordinates per vertex (Mitsuba's, for rectangles and cubes)


@dataclass
class RectLight:
    """A one-sided parallelogram emitter: points ``center + s*half_u + t*half_v``, s, t in [-1, 1].

    It emits ``radiance`` (W sr^-1 m^-2 per channel) to the side of ``normal``.
    """

    center: np.ndarray
    half_u: np.ndarray
    half_v: np.ndarray
    normal: np.ndarray
    radiance: tuple[float, float, float]

    @property
    def area(self) -> float:
        return float(4.0 * np.linalg.norm(np.cross(self.half_u, self.half_v)))

    def corners(self) -> np.ndarray:
        c, u, v = self.center, self.half_u, self.half_v
        return np.array([c - u - v, c + u - v, c + u + v, c - u + v])


@dataclass
class SphereLight:
    """Mitsuba's ``area`` emitter on ``Scene.spheres[sphere]``: ``radiance`` outwards (one-sided, as Mitsuba)."""

    sphere: int
    radiance: tuple[float, float, float]


@dataclass
class MeshLight:
    """Mitsuba's ``area`` emitter on the triangle mesh ``Scene.meshes[mesh]``, to the side its normals face."""

    mesh: int
    radiance: tuple[float, float, float]


@dataclass
class PointLight:
    """Mitsuba's ``point``: ``intensity`` (W/sr) from ``position``; a surface at distance d receives I / d^2."""

    position: np.ndarray
    intensity: tuple[float, float, float]


@dataclass
class SpotLight:
    """Mitsuba's ``spot``: a point light along local +z of ``to_world`` (3x3 rotation) whose intensity falls off
    linearly in angle from ``beam_width`` to 0 at ``cutoff_angle`` (degrees)."""

    position: np.ndarray
    to_world: np.ndarray
    intensity: tuple[float, float, float]
    cutoff_angle: float = 20.0
    beam_width: float = 15.0


@dataclass
class DirectionalLight:
    """Mitsuba's ``directional``: ``irradiance`` (W/m^2 across the beam) travelling along unit ``direction``."""

    direction: np.ndarray
    irradiance: tuple[float, float, float]


@dataclass
class EnvMap:
    """Mitsuba's ``envmap``: linear RGB ``image`` (H, W, 3) in latitude-longitude layout (kernels/envmap.py), its
    frame ``to_world`` (3x3: directions) and a radiance ``scale``."""

    image: np.ndarray
    to_world: np.ndarray
    scale: float = 1.0
    filename: str = ""


@dataclass
class Integrator:
    """Mitsuba's ``path`` integrator parameters (its ``direct`` is ``path`` with max_depth 2: the same paths and
    MIS, equal in expectation), possibly nested in its ``moment`` integrator.

    max_depth: longest path in segments; -1 unlimited, 1 = emitters seen directly, 2 = direct lighting.
    rr_depth: depth at which throughput-based Russian roulette starts.
    light_samples: next-event samples per light the file asks for (``direct``'s emitter_samples), None: the
    renderer's default.
    """

    max_depth: int = -1
    rr_depth: int = 5
    hide_emitters: bool = False
    kind: str = "path"
    light_samples: int | None = None
    moment: str | None = None  # Mitsuba's moment integrator around this one: the nested integrator's name

    @property
    def layer_names(self) -> tuple[str, ...]:
        """The extra image layers this integrator writes, as Mitsuba names them: the nested integrator's mean XYZ
        and its per-sample second moment (m2_ prefix), channels X, Y, Z each."""
        return () if self.moment is None else (self.moment, "m2_" + self.moment)


@dataclass
class Scene:
    camera: Camera
    width: int = 768
    height: int = 576
    spp: int = 4
    sampler_seed: int = 0
    integrator: Integrator = field(default_factory=Integrator)
    materials: list[Material] = field(default_factory=list)
    spheres: list[Sphere] = field(default_factory=list)
    meshes: list[TriangleMesh] = field(default_factory=list)
    lights: list[RectLight] = field(default_factory=list)
    sphere_lights: list[SphereLight] = field(default_factory=list)
    mesh_lights: list[MeshLight] = field(default_factory=list)
    point_lights: list[PointLight] = field(default_factory=list)
    spot_lights: list[SpotLight] = field(default_factory=list)
    directional_lights: list[DirectionalLight] = field(default_factory=list)
    environment: tuple[float, float, float] | None = None  # Mitsuba's ``constant`` emitter: radiance from every direction
    textures: list[Texture] = field(default_factory=list)
    envmap: EnvMap | None = None  # Mitsuba's ``envmap`` emitter (at most one environment: this or ``environment``)
    source: str = "<scene>"
    rfilter: PixelFilter = field(default_factory=PixelFilter)  # the loader gives Mitsuba's default, gaussian
    sample_border: bool = False  # Mitsuba's film option: sample ceil(radius - 0.5) pixels beyond the film's edges

    def add_material(self, material: Material) -> int:
        """Index of ``material``, adding it if new."""
        for i, m in enumerate(self.materials):
            if m == material and m.name == material.name:
                return i
        self.materials.append(material)
        return len(self.materials) - 1

    @property
    def only_rect_lights(self) -> bool:
        """Are the parallelogram lights (``lights``) the only emitters?"""
        return not (self.sphere_lights or self.mesh_lights or self.point_lights or self.spot_lights
                    or self.directional_lights or self.environment is not None or self.envmap is not None)

    @property
    def triangle_count(self) -> int:
        return sum(len(m.faces) for m in self.meshes)

    @property
    def has_mirror(self) -> bool:
        used = {s.material for s in self.spheres} | {m.material for m in self.meshes}
        return any(self.materials[i].kind == "mirror" for i in used)

    @property
    def has_delta_bsdf(self) -> bool:
        """Is any surface a mirror, glass or a smooth conductor (caustics behind it are found by BSDF sampling
        alone)?"""
        used = {s.material for s in self.spheres} | {m.material for m in self.meshes}
        return any(self.materials[i].kind in DELTA_KINDS for i in used)

    @property
    def has_smooth_normals(self) -> bool:
        return any(m.normals is not None for m in self.meshes)

    def extent(self) -> float:
        """Largest absolute world coordinate of any geometry or the camera (scale for ray offsets)."""
        parts = [np.abs(self.camera.to_world[:3, 3])]
        parts += [np.abs(m.vertices).max() for m in self.meshes if len(m.vertices)]  # (axis-0 max: 15x slower)
        parts += [np.abs(s.center) + s.radius for s in self.spheres]
        return float(np.max(np.concatenate([np.atleast_1d(p) for p in parts])))
