"""Scene loading: Mitsuba 3 XML files and Mitsuba-shaped dicts -> :class:`pathtracer.scene.Scene`.

``load_file`` parses XML into the dict shape that ``mi.load_dict`` accepts
(``pathtracer.loader_xml``) and hands it to the same code as ``load_dict``, so every plugin's
semantics, defaults and checks live here, once. Supported subset, with Mitsuba 3's defaults:

=========== ============ ==========================================================================
element     type         properties (default)
=========== ============ ==========================================================================
integrator  path         max_depth (-1, unlimited; >= -1), rr_depth (5; > 0), hide_emitters (false)
integrator  moment       the nested integrator (one path or direct) and its mean XYZ and per-sample
                         second moment as EXR layers <name>.XYZ and m2_<name>.XYZ, as Mitsuba
integrator  direct       path with max_depth 2 (the same paths and MIS); emitter_samples (or
                         shading_samples, 1) are next-event samples per light, bsdf_samples (1) one
                         BSDF sample; delta lights are not multiplied by emitter_samples (Mitsuba
                         3.9.1 does that: its bug #1861)
sensor      perspective  fov (degrees, 0 < fov < 180) with fov_axis (x | y | diagonal | smaller |
                         larger), or focal_length ("50mm": the diagonal fov of a 36 x 24 mm film),
                         near_clip (0.01), far_clip (10000), to_world (rigid); focus_distance,
                         shutter_open/close and principal_point_offset_x/y (0 only) are accepted
sensor      thinlens     the same, and aperture_radius (required), focus_distance (far_clip)
sampler     independent  sample_count (4; > 0), seed (0)
film        hdrfilm      width (768), height (576), sample_border (false), crop_* (the whole film
                         only), file_format, banner, compensate (they only change Mitsuba's own
                         output file), pixel_format (rgb only), component_format
                         (float16 | float32; storage precision only, never changes the image);
                         rfilter (gaussian, Mitsuba's default, when none is given)
rfilter     box          (radius 0.5: each sample counts in its own pixel)
rfilter     tent         radius (1.0; in (0, 64] pixels)
rfilter     gaussian     stddev (0.5; in (0, 64] pixels), radius 4 stddev
bsdf        diffuse      reflectance (0.5; rgb or float in [0, 1])
bsdf        conductor    material (a name of Mitsuba's table, or "none": a perfect mirror) or eta
                         (0) and k (1), specular_reflectance (1.0)
bsdf        roughconductor  the same, distribution (beckmann | ggx), alpha (0.1; >= 0; or
                         alpha_u = alpha_v: isotropic only), sample_visible (noise only)
bsdf        dielectric   int_ior ("bk7"), ext_ior ("air"): a number or a name of Mitsuba's table,
                         specular_reflectance, specular_transmittance (1.0)
bsdf        thindielectric  the same
bsdf        plastic      diffuse_reflectance (0.5), specular_reflectance (1.0), int_ior
                         ("polypropylene"), ext_ior ("air"), nonlinear (false)
bsdf        roughplastic the same, distribution (beckmann | ggx), alpha (0.1; >= 0; a number, as
                         Mitsuba), sample_visible (noise only)
bsdf        twosided     exactly one nested bsdf (one-sided ones then reflect on both sides)
texture     checkerboard color0 (0.4), color1 (0.2), to_uv; on reflectance, diffuse_reflectance or
                         specular_reflectance of spheres, rectangles, cubes and obj, ply and
                         serialized meshes (Mitsuba's uv; a mesh without texture coordinates gets
                         each face's barycentric (b1, b2), as in Mitsuba)
texture     bitmap       filename (OpenEXR, or PNG or JPEG read as sRGB), filter_type (bilinear | nearest),
                         wrap_mode (repeat | mirror | clamp), to_uv, format and accel (storage only);
                         raw=true is refused; values in [0, 1]
shape       sphere       center (0), radius (1; > 0), to_world (translation, rotation and uniform
                         scale only; no mirroring, which turns Mitsuba's sphere inside out);
                         Mitsuba composes to_world * translate(center) * scale(radius)
shape       rectangle    to_world; [-1, 1]^2 at z = 0 with normal +z
shape       cube         to_world; [-1, 1]^3, Mitsuba's 24 vertices and 12 outward triangles
shape       disk         to_world, flip_normals; the unit disk at z = 0 (normal +z) as a 1024-gon of
                         the same area (pathtracer/tessellate.py: outline within 3.2e-6 r)
shape       cylinder     p0 (0), p1 (0, 0, 1), radius (1; > 0), to_world, flip_normals; open ends,
                         normals outwards; a 1024-sided prism of the same lateral area with radial
                         shading normals (outline within 3.2e-6 r)
shape       serialized   filename (Mitsuba's compressed format, versions 3 and 4), shape_index (0),
                         face_normals, to_world; normals as the file's, else recomputed as Mitsuba
shape       obj, ply     filename (relative to the scene file; for load_dict, to the working
                         directory), face_normals (false), flip_tex_coords (v -> 1 - v; true for
                         obj, false for ply, as Mitsuba 3.9), to_world
emitter     area         radiance (1.0, >= 0) on any shape, nested or referenced by id (one shape
                         each; an area emitter no shape refers to emits nothing, as in Mitsuba)
emitter     point        intensity (1.0), position or to_world (translation only)
emitter     spot         intensity, cutoff_angle (20), beam_width (3/4 cutoff), to_world (local +z)
emitter     directional  irradiance (1.0), direction or to_world (local +z)
emitter     constant     radiance (1.0); one environment per scene
emitter     envmap       filename (an OpenEXR, Radiance HDR or PNG latitude-longitude map), scale (1.0; >= 0),
                         to_world (rotation only), mis_compensation (noise only); one
                         environment per scene
=========== ============ ==========================================================================

Every shape takes ``flip_normals`` = false only and at most one bsdf (inline or ``ref``); a shape
with no bsdf gets diffuse 0.5, an emitting shape with no bsdf gets a black diffuse (Mitsuba's
``Shape`` constructor). Mesh normals and winding follow the side Mitsuba shades as the front:
rectangles and cubes transform their normal as a normal (inverse transpose), so under a mirroring
``to_world`` their triangles are rewound to keep the face normal on that side; a file mesh with
vertex normals is rewound the same way; a mesh whose normals are recomputed (angle-weighted, in
world space) or flat (``face_normals``) keeps its world-space winding, as in Mitsuba.

Colours may also be ``<spectrum>`` values (pathtracer/spectra.py converts them as Mitsuba's RGB variants
do); ``<include>`` and ``<path>`` follow Mitsuba's file resolver (pathtracer/loader_xml.py).

XML follows Mitsuba 3.9's parser: ``<default>`` and ``$name`` substitution in document order
(longest names first, a backslash escapes a dollar), a parameter passed but never used is an
error, transform operations left-multiply. One difference on purpose: a ``<rotate>`` axis must be
a unit vector (Mitsuba 3.9 does not normalize it, so another length would not be a rotation
there). Dicts may also give a colour as a plain 3-sequence, which ``mi.load_dict`` refuses.

Anything else (an unknown plugin, property, tag or attribute, a wrong type, NaN or infinity, a
value out of range, a dangling reference) raises :class:`SceneError` naming the source, the
element and what is supported. Nothing is ignored or approximated silently.
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import imageio, meshio, spectra, tessellate
from .errors import ImageIOError
from .material_data import CONDUCTOR_RGB, IOR as IOR_TABLE
from . import transform as tf
from .errors import SceneError
from .loader_xml import Point3, XmlDict, parse_file, resolve_file
from .scene import (DEFAULT_MATERIAL, Camera, DirectionalLight, EnvMap, Integrator, Texture, Material, MeshLight, PixelFilter,
                    PointLight, RectLight, Scene, Sphere, SphereLight, SpotLight, TriangleMesh)

FLOAT, INT, BOOL, STRING, POINT, COLOR, TRANSFORM = "float", "integer", "boolean", "string", "point", "rgb", "transform"
IOR = "ior"  # a number, or a name of Mitsuba's table of indices of refraction
UINT32_MAX = 2**32 - 1


@dataclass(frozen=True)
class Plugin:
    category: str
    props: dict
    nested: tuple = field(default=())


PLUGINS = {
    "path": Plugin("integrator", {"max_depth": INT, "rr_depth": INT, "hide_emitters": BOOL}),
    "moment": Plugin("integrator", {}, ("integrator",)),
    "direct": Plugin("integrator", {"shading_samples": INT, "emitter_samples": INT, "bsdf_samples": INT,
                                    "hide_emitters": BOOL}),
    "perspective": Plugin("sensor", {"fov": FLOAT, "focal_length": STRING, "fov_axis": STRING, "near_clip": FLOAT,
                                     "far_clip": FLOAT, "focus_distance": FLOAT, "principal_point_offset_x": FLOAT,
                                     "principal_point_offset_y": FLOAT, "shutter_open": FLOAT,
                                     "shutter_close": FLOAT, "to_world": TRANSFORM}, ("film", "sampler")),
    "thinlens": Plugin("sensor", {"fov": FLOAT, "focal_length": STRING, "fov_axis": STRING, "near_clip": FLOAT,
                                  "far_clip": FLOAT, "focus_distance": FLOAT, "aperture_radius": FLOAT,
                                  "shutter_open": FLOAT, "shutter_close": FLOAT, "to_world": TRANSFORM},
                       ("film", "sampler")),
    "independent": Plugin("sampler", {"sample_count": INT, "seed": INT}),
    "hdrfilm": Plugin("film", {"width": INT, "height": INT, "pixel_format": STRING, "component_format": STRING,
                               "file_format": STRING, "banner": BOOL, "compensate": BOOL, "sample_border": BOOL,
                               "crop_offset_x": INT, "crop_offset_y": INT, "crop_width": INT, "crop_height": INT},
                      ("rfilter",)),
    "box": Plugin("rfilter", {}),
    "tent": Plugin("rfilter", {"radius": FLOAT}),
    "gaussian": Plugin("rfilter", {"stddev": FLOAT}),
    "diffuse": Plugin("bsdf", {"reflectance": COLOR}),
    "conductor": Plugin("bsdf", {"material": STRING, "eta": COLOR, "k": COLOR, "specular_reflectance": COLOR}),
    "roughconductor": Plugin("bsdf", {"material": STRING, "eta": COLOR, "k": COLOR, "specular_reflectance": COLOR,
                                      "distribution": STRING, "alpha": FLOAT, "alpha_u": FLOAT, "alpha_v": FLOAT,
                                      "sample_visible": BOOL}),
    "dielectric": Plugin("bsdf", {"int_ior": IOR, "ext_ior": IOR, "specular_reflectance": COLOR,
                                  "specular_transmittance": COLOR}),
    "thindielectric": Plugin("bsdf", {"int_ior": IOR, "ext_ior": IOR, "specular_reflectance": COLOR,
                                      "specular_transmittance": COLOR}),
    "plastic": Plugin("bsdf", {"diffuse_reflectance": COLOR, "specular_reflectance": COLOR, "int_ior": IOR,
                               "ext_ior": IOR, "nonlinear": BOOL}),
    "roughplastic": Plugin("bsdf", {"diffuse_reflectance": COLOR, "specular_reflectance": COLOR, "int_ior": IOR,
                                    "ext_ior": IOR, "nonlinear": BOOL, "distribution": STRING, "alpha": FLOAT,
                                    "sample_visible": BOOL}),
    "twosided": Plugin("bsdf", {}, ("bsdf",)),
    "checkerboard": Plugin("texture", {"color0": COLOR, "color1": COLOR, "to_uv": TRANSFORM}),
    # format and accel only choose how Mitsuba stores and looks up the texels (the same values): accepted
    "bitmap": Plugin("texture", {"filename": STRING, "filter_type": STRING, "wrap_mode": STRING, "raw": BOOL,
                                 "to_uv": TRANSFORM, "format": STRING, "accel": BOOL}),
    "sphere": Plugin("shape", {"center": POINT, "radius": FLOAT, "to_world": TRANSFORM, "flip_normals": BOOL},
                     ("bsdf", "emitter")),
    "rectangle": Plugin("shape", {"to_world": TRANSFORM, "flip_normals": BOOL}, ("bsdf", "emitter")),
    "cube": Plugin("shape", {"to_world": TRANSFORM, "flip_normals": BOOL}, ("bsdf", "emitter")),
    "disk": Plugin("shape", {"to_world": TRANSFORM, "flip_normals": BOOL}, ("bsdf", "emitter")),
    "cylinder": Plugin("shape", {"p0": POINT, "p1": POINT, "radius": FLOAT, "to_world": TRANSFORM,
                                 "flip_normals": BOOL}, ("bsdf", "emitter")),
    "obj": Plugin("shape", {"filename": STRING, "face_normals": BOOL, "flip_tex_coords": BOOL,
                            "to_world": TRANSFORM, "flip_normals": BOOL}, ("bsdf", "emitter")),
    "ply": Plugin("shape", {"filename": STRING, "face_normals": BOOL, "flip_tex_coords": BOOL,
                            "to_world": TRANSFORM, "flip_normals": BOOL}, ("bsdf", "emitter")),
    "serialized": Plugin("shape", {"filename": STRING, "shape_index": INT, "face_normals": BOOL,
                                   "to_world": TRANSFORM, "flip_normals": BOOL}, ("bsdf", "emitter")),
    # sampling_weight only changes how often Mitsuba picks an emitter (noise, not the image): accepted
    "area": Plugin("emitter", {"radiance": COLOR, "sampling_weight": FLOAT}),
    "point": Plugin("emitter", {"intensity": COLOR, "position": POINT, "to_world": TRANSFORM,
                                "sampling_weight": FLOAT}),
    "spot": Plugin("emitter", {"intensity": COLOR, "cutoff_angle": FLOAT, "beam_width": FLOAT, "to_world": TRANSFORM,
                               "sampling_weight": FLOAT}),
    "directional": Plugin("emitter", {"irradiance": COLOR, "direction": POINT, "to_world": TRANSFORM,
                                      "sampling_weight": FLOAT}),
    "constant": Plugin("emitter", {"radiance": COLOR, "sampling_weight": FLOAT}),
    # mis_compensation only changes how Mitsuba samples the map (noise, not the image): accepted
    "envmap": Plugin("emitter", {"filename": STRING, "scale": FLOAT, "to_world": TRANSFORM, "mis_compensation": BOOL,
                                 "sampling_weight": FLOAT}),
}

# Mitsuba 3 plugins we do not support, by category: for dict scenes (where only the type names
# the category) and for messages that say what is supported instead.
MITSUBA_TYPES = {
    "integrator": "direct path volpath volpathmis aov ptracer prb prb_basic prb_projective direct_projective "
                  "moment stokes depth",
    "sensor": "perspective thinlens orthographic radiancemeter irradiancemeter distant batch",
    "film": "hdrfilm specfilm",
    "sampler": "independent stratified multijitter orthogonal ldsampler",
    "rfilter": "box tent gaussian mitchell catmullrom lanczos",
    "bsdf": "diffuse conductor roughconductor dielectric roughdielectric thindielectric plastic roughplastic "
            "twosided principled principledthin blendbsdf mask null bumpmap normalmap measured "
            "measured_polarized polarizer retarder circular pplastic hair",
    "shape": "sphere rectangle cube obj ply disk cylinder serialized shapegroup instance bsplinecurve "
             "linearcurve sdfgrid ellipsoids ellipsoidsmesh merge",
    "emitter": "area point spot constant envmap directional directionalarea projector sunsky",
    "texture": "bitmap checkerboard mesh_attribute volume",
}
TYPE_CATEGORY = {t: cat for cat, names in MITSUBA_TYPES.items() for t in names.split()}
VALUE_TYPES = {"rgb", "spectrum", "ref"}
HINTS: dict[str, str] = {}
FOV_AXES = ("x", "y", "diagonal", "smaller", "larger")
EMISSIVE = ("radiance", "intensity", "irradiance")  # the emitters' colours

# Mitsuba's cube: 4 vertices per face (normals -y, +y, +x, +z, -x, -z), 2 triangles each.
_CUBE_VERTICES = np.array([
    [1, -1, -1], [1, -1, 1], [-1, -1, 1], [-1, -1, -1], [1, 1, -1], [-1, 1, -1], [-1, 1, 1], [1, 1, 1],
    [1, -1, -1], [1, 1, -1], [1, 1, 1], [1, -1, 1], [1, -1, 1], [1, 1, 1], [-1, 1, 1], [-1, -1, 1],
    [-1, -1, 1], [-1, 1, 1], [-1, 1, -1], [-1, -1, -1], [1, 1, -1], [1, -1, -1], [-1, -1, -1], [-1, 1, -1],
], dtype=np.float64)
_CUBE_FACES = np.array([[4 * i + a for a in tri] for i in range(6) for tri in ((0, 1, 2), (3, 0, 2))],
                       dtype=np.int64)
_RECT_VERTICES = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], dtype=np.float64)


def load_file(path: str | os.PathLike, **params) -> Scene:
    """Load a Mitsuba 3 XML scene; ``params`` override its ``<default>`` values (like ``mi.load_file``).

    Values may be Python numbers, bools or strings. A parameter the file never refers to is an
    error, as in Mitsuba. Mesh filenames are relative to the scene file.
    """
    with np.errstate(all="ignore"):  # overflow is reported as a SceneError where a value is checked
        d = parse_file(path, params)
    return _Builder(str(path), Path(path).parent, d.search_paths).build(d)


def load_dict(d: Mapping, source: str = "<dict>") -> Scene:
    """Load a Mitsuba-shaped scene dict (as ``mi.load_dict`` takes: ``{'type': 'scene', ...}``).

    Colours may be ``{'type': 'rgb', 'value': [r, g, b]}``, a float or a 3-sequence; ``to_world`` a
    4x4 nested list or array, a ``mi.ScalarTransform4f`` or a :class:`pathtracer.transform.Transform`;
    ``{'type': 'ref', 'id': key}`` refers to a top-level key (or a nested dict's ``'id'``).
    """
    return _Builder(source, Path.cwd()).build(d)


# -- helpers --------------------------------------------------------------------------------------


def _is_number(v) -> bool:
    return isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, (bool, np.bool_))


def _float(v) -> float:
    """float(v), with Python ints too large for a float mapped to infinity (then refused as not finite)."""
    try:
        return float(v)
    except OverflowError:
        return float("inf")


def _is_plugin(v) -> bool:
    return isinstance(v, Mapping) and isinstance(v.get("type"), str)


def _show(v) -> str:
    if isinstance(v, np.ndarray):
        text = f"array of shape {v.shape}"
    else:
        text = " ".join(repr(v).split())
        if len(text) > 40:
            text = text[:37] + "..."
    return f"{type(v).__name__} {text}" if not isinstance(v, (bool, int, float, str)) else text


def _where(node: Mapping, path: str) -> str:
    if isinstance(node, XmlDict):
        return node.where
    t = node.get("type")
    return f"{path or 'scene dict'} (type \"{t if isinstance(t, str) else _show(t)}\")"


def _prop_where(node: Mapping, path: str, key: str) -> str:
    if isinstance(node, XmlDict):
        return node.prop_where.get(key, node.where)
    return f"{path}[{key!r}]"


def _category(node: Mapping) -> str | None:
    if isinstance(node, XmlDict):
        return node.category
    return TYPE_CATEGORY.get(node["type"])


def _supported(spec: Plugin) -> str:
    names = [f"{k} (false only)" if k == "flip_normals" else k for k in spec.props]
    return ", ".join(names + list(spec.nested)) or "none"


def _types_of(category: str) -> str:
    return ", ".join(sorted(t for t, p in PLUGINS.items() if p.category == category))


def _check_invertible(linear: np.ndarray) -> bool:
    scale = float(np.prod(np.linalg.norm(linear, axis=0)))
    return abs(float(np.linalg.det(linear))) > 1e-12 * scale


@dataclass
class _Obj:
    """A nested plugin dict with its path (for errors) and the place it was written."""

    node: Mapping
    path: str
    category: str


class _Builder:
    def __init__(self, source: str, base_dir: Path, search_paths: list | None = None):
        self.source = source
        self.base_dir = base_dir
        # where mesh files are looked for: <path> folders, the scene's folder, the working directory (Mitsuba's
        # file resolver; pathtracer.loader_xml.resolve_file)
        self.search_paths = search_paths if search_paths is not None else [base_dir]
        self.ids: dict[str, tuple[Mapping, str]] = {}
        self.node_ids: dict[int, str] = {}  # id(node) -> its id (or top-level dict key): names its parameters
        self.materials: dict[int, Material] = {}
        self.textures: list[Texture] = []  # every texture a material uses (Scene.textures)
        self.texture_nodes: dict[int, Texture] = {}
        self.visiting: set[int] = set()
        self.attached: set[int] = set()  # area emitters already attached to a shape

    def fail(self, where: str, problem: str):
        raise SceneError(self.source, " ".join(where.split()), " ".join(problem.split()))

    def build(self, d) -> Scene:
        # Every number is checked for finiteness where it is used: overflow is an error, not a warning.
        with np.errstate(all="ignore"):
            return self.scene(d)

    # -- structure ----------------------------------------------------------------------------

    def register(self, node: Mapping, path: str, key_id: str | None, depth: int = 0):
        if depth > 64:
            self.fail(_where(node, path), "plugins are nested too deeply (a dict that contains itself?)")
        ids = [] if key_id is None else [key_id]
        if "id" in node:
            if not isinstance(node["id"], str) or not node["id"]:
                self.fail(_prop_where(node, path, "id"), f'"id" must be a non-empty string (got {_show(node["id"])})')
            if node["id"] != key_id:
                ids.append(node["id"])
        if ids:
            self.node_ids[id(node)] = node["id"] if isinstance(node.get("id"), str) and node["id"] else ids[0]
        for i in ids:
            if i in self.ids:
                self.fail(_where(node, path), f'duplicate id "{i}" (also used by {_where(*self.ids[i])})')
            self.ids[i] = (node, path)
        for k, v in node.items():
            if _is_plugin(v) and v["type"] not in VALUE_TYPES:
                self.register(v, f"{path}[{k!r}]", None, depth + 1)

    def spec(self, node: Mapping, path: str, expected: tuple) -> Plugin:
        t = node["type"]
        cat = _category(node)
        where = _where(node, path)
        if cat is None:
            self.fail(where, f'unknown plugin type "{t}" (supported: {", ".join(sorted(PLUGINS))})')
        if cat not in expected:
            self.fail(where, f"a {cat} cannot appear here (expected: {' or '.join(expected)})")
        spec = PLUGINS.get(t)
        if spec is None or spec.category != cat:
            self.fail(where, f'{cat} type "{t}" is not supported (supported: {_types_of(cat) or "none"})')
        return spec

    def resolve(self, ref: Mapping, where: str) -> tuple[Mapping, str]:
        extra = [k for k in ref if k not in ("type", "id")]
        if extra:
            self.fail(where, f'a ref takes only "id" (got {", ".join(map(str, extra))})')
        rid = ref.get("id")
        if not isinstance(rid, str):
            self.fail(where, f'a ref needs a string "id" (got {_show(rid)})')
        if rid not in self.ids:
            known = ", ".join(sorted(self.ids)) or "none"
            self.fail(where, f'reference to unknown id "{rid}" (ids defined: {known})')
        return self.ids[rid]

    def fields(self, node: Mapping, path: str, spec: Plugin) -> tuple[dict, list[_Obj]]:
        """Split a plugin dict into its properties and its nested objects (refs resolved)."""
        props, objs = {}, []
        for k, v in node.items():
            if k in ("type", "id"):
                continue
            if not isinstance(k, str):
                self.fail(_where(node, path), f"keys must be strings (got {_show(k)})")
            if k in spec.props:
                props[k] = v
            elif _is_plugin(v) and v["type"] == "ref":
                target, tpath = self.resolve(v, _prop_where(node, path, k))
                objs.append(_Obj(target, tpath, _category(target) or ""))
            elif _is_plugin(v) and v["type"] not in VALUE_TYPES:
                objs.append(_Obj(v, f"{path}[{k!r}]", _category(v) or ""))
            else:
                self.fail(_where(node, path), f'property "{k}" is not supported '
                                              f'(supported: {_supported(spec)}){HINTS.get(k, "")}')
        for o in objs:
            if o.category not in spec.nested:
                what = f'a {o.category}' if o.category else f'unknown plugin type "{o.node["type"]}"'
                self.fail(_where(o.node, o.path), f'{what} cannot appear inside {_where(node, path)} '
                                                  f'(supported there: {_supported(spec)})')
        return props, objs

    def one(self, objs: list[_Obj], category: str, parent: str) -> _Obj | None:
        found = [o for o in objs if o.category == category]
        if len(found) > 1:
            self.fail(_where(found[1].node, found[1].path), f"only one {category} is allowed in {parent}")
        return found[0] if found else None

    # -- values -------------------------------------------------------------------------------

    def value(self, node: Mapping, path: str, props: dict, key: str, kind: str, default=None):
        if key not in props:
            return default
        v = props[key]
        where = _prop_where(node, path, key)
        if _is_plugin(v) and (_category(v) == "texture" or v["type"] == "ref"):
            self.fail(where, f"{key}: a texture is not supported here (give a value)")
        if kind == FLOAT:
            if not _is_number(v):
                self.fail(where, f"{key} must be a number (got {_show(v)})")
            if not np.isfinite(_float(v)):
                self.fail(where, f"{key} must be a finite number (got {_show(v)})")
            return _float(v)
        if kind == INT:
            if not isinstance(v, (int, np.integer)) or isinstance(v, (bool, np.bool_)):
                self.fail(where, f"{key} must be an integer (got {_show(v)})")
            return int(v)
        if kind == BOOL:
            if not isinstance(v, (bool, np.bool_)):
                self.fail(where, f"{key} must be a boolean (got {_show(v)})")
            return bool(v)
        if kind == STRING:
            if not isinstance(v, str):
                self.fail(where, f"{key} must be a string (got {_show(v)})")
            return v
        if kind == IOR:
            if isinstance(v, str):
                name = v.lower()
                if name not in IOR_TABLE:
                    self.fail(where, f'unknown {key} "{v}" (known: {", ".join(IOR_TABLE)}; or give a number)')
                return IOR_TABLE[name]
            if not _is_number(v) or not np.isfinite(_float(v)):
                self.fail(where, f"{key} must be a finite number or a material name (got {_show(v)})")
            return self.in_range(where, key, _float(v), _float(v) > 0.0, "> 0")
        if kind == POINT:
            return self.vec3(v, where, key, "a point (3 numbers)")
        if kind == COLOR:
            return self.colour(v, where, key)
        if kind == TRANSFORM:
            return self.matrix(v, where, key)
        raise AssertionError(kind)

    def vec3(self, v, where: str, key: str, what: str) -> np.ndarray:
        if isinstance(v, (Mapping, str, bytes)) or _is_number(v) or isinstance(v, (bool, np.bool_)):
            self.fail(where, f"{key} must be {what} (got {_show(v)})")
        try:
            items = list(v)
        except TypeError:
            self.fail(where, f"{key} must be {what} (got {_show(v)})")
        if len(items) != 3 or not all(_is_number(x) for x in items):
            self.fail(where, f"{key} must be {what} (got {_show(v)})")
        a = np.array([_float(x) for x in items])
        if not np.all(np.isfinite(a)):
            self.fail(where, f"{key} must be finite (got {a.tolist()})")
        return a

    def colour(self, v, where: str, key: str) -> tuple[float, float, float]:
        if isinstance(v, Point3):
            self.fail(where, f"{key} must be an <rgb> or a <float>, not a point or vector")
        if _is_plugin(v) and v["type"] == "spectrum":
            # converted as Mitsuba's RGB variants do; an emitter's radiance, intensity or irradiance is not a
            # reflectance (no D65 weighting, no [0, 1] bound)
            try:
                return spectra.spectrum_to_rgb(v, emitter=key in EMISSIVE)
            except ValueError as e:
                self.fail(where, f"{key}: {e}")
        if _is_plugin(v):
            if v["type"] != "rgb":
                self.fail(where, f'{key}: "{v["type"]}" is not supported (give an rgb value or a float)')
            extra = [k for k in v if k not in ("type", "value")]
            if extra:
                self.fail(where, f'an rgb value takes only "value" (got {", ".join(map(str, extra))})')
            if "value" not in v:
                self.fail(where, f'{key}: an rgb value needs "value"')
            v = v["value"]
        if _is_number(v):
            if not np.isfinite(_float(v)):
                self.fail(where, f"{key} must be finite (got {_show(v)})")
            return (_float(v),) * 3
        return tuple(self.vec3(v, where, key, "an rgb value (3 numbers) or a float").tolist())

    def matrix(self, v, where: str, key: str) -> np.ndarray:
        raw = v.matrix if hasattr(v, "matrix") and not isinstance(v, np.ndarray) else v
        if isinstance(raw, (Mapping, str, bytes)) or _is_number(raw):
            self.fail(where, f"{key} must be a 4x4 matrix or a transform (got {_show(v)})")
        try:
            m = np.array(raw, dtype=np.float64)
        except (TypeError, ValueError, OverflowError):
            self.fail(where, f"{key} must be a 4x4 matrix or a transform (got {_show(v)})")
        if m.shape != (4, 4):
            self.fail(where, f"{key} must be a 4x4 matrix (got shape {m.shape})")
        if not np.all(np.isfinite(m)):
            self.fail(where, f"{key} has NaN or infinite entries")
        if np.max(np.abs(m[3] - (0.0, 0.0, 0.0, 1.0))) > 1e-9:
            self.fail(where, f"{key} must be affine (last row 0 0 0 1, got {m[3].tolist()})")
        return m

    def in_range(self, where: str, key: str, v, ok: bool, rule: str):
        if not ok:
            self.fail(where, f"{key} must be {rule} (got {v})")
        return v

    # -- plugins ------------------------------------------------------------------------------

    def scene(self, d) -> Scene:
        if not isinstance(d, Mapping):
            self.fail("", f"a scene must be a dict (got {_show(d)})")
        if not (_is_plugin(d) and d["type"] == "scene"):
            self.fail(_where(d, ""), 'the top-level dict must have "type": "scene"')
        for k, v in d.items():
            if _is_plugin(v) and v["type"] not in VALUE_TYPES:
                named = not isinstance(d, XmlDict) or "id" in v
                self.register(v, f"[{k!r}]", k if named and isinstance(k, str) else None)

        integrators, sensors, shapes, emitters = [], [], [], []
        for k, v in d.items():
            if k == "type":
                continue
            path = f"[{k!r}]"
            if not _is_plugin(v) or v["type"] in VALUE_TYPES:
                what = "a ref" if _is_plugin(v) and v["type"] == "ref" else f'"{k}"'
                self.fail(_prop_where(d, "", k), f"{what} cannot appear at scene level (a scene holds integrator, "
                                                 f"sensor, shape and bsdf plugins)")
            cat = _category(v)
            if cat in ("film", "sampler", "rfilter"):
                parent = "film" if cat == "rfilter" else "sensor"
                self.fail(_where(v, path), f"a {cat} must be nested in the {parent}")
            self.spec(v, path, ("integrator", "sensor", "shape", "bsdf", "emitter", "texture"))
            if cat == "emitter":
                emitters.append((v, path))
            elif cat == "integrator":
                integrators.append((v, path))
            elif cat == "sensor":
                sensors.append((v, path))
            elif cat == "shape":
                shapes.append((v, path, k))
            elif cat == "texture":
                self.texture(v, path)  # checked even when unused, as Mitsuba instantiates it
            else:
                self.material(v, path)  # checked even when unused, as Mitsuba instantiates it
        if len(integrators) > 1:
            self.fail(_where(*integrators[1]), "only one integrator can be specified per scene")
        if not sensors:
            self.fail(_where(d, ""), 'the scene has no sensor (a "perspective" sensor with a "fov" is required)')
        if len(sensors) > 1:
            self.fail(_where(*sensors[1]), "only one sensor is supported")

        scene = self.sensor(*sensors[0])
        scene.source = self.source
        if integrators:
            scene.integrator = self.integrator(*integrators[0])
        for node, path, key in shapes:
            self.shape(node, path, key, scene)
        for node, path in emitters:
            self.scene_emitter(node, path, scene)
        return scene

    def emitter_colour(self, node: Mapping, path: str, props: dict, key: str) -> tuple:
        c = self.value(node, path, props, key, COLOR, (1.0, 1.0, 1.0))
        if not all(x >= 0.0 for x in c):
            self.fail(_prop_where(node, path, key), f"{key} must be >= 0 (got {list(c)})")
        return c

    def scene_emitter(self, node: Mapping, path: str, scene: Scene):
        """An emitter at scene level: point, spot, directional or constant (an area emitter there belongs to the
        shape that refers to it; one that no shape refers to emits nothing, as in Mitsuba)."""
        spec = self.spec(node, path, ("emitter",))
        props, _ = self.fields(node, path, spec)
        t = node["type"]
        w = lambda k: _prop_where(node, path, k)  # noqa: E731
        if "sampling_weight" in props:
            sw = self.value(node, path, props, "sampling_weight", FLOAT)
            self.in_range(w("sampling_weight"), "sampling_weight", sw, sw >= 0, ">= 0")
        if t == "area":
            return  # attached where a shape refers to it, or (as in Mitsuba) dropped
        if t in ("constant", "envmap"):
            if scene.environment is not None or scene.envmap is not None:
                self.fail(_where(node, path), "only one environment emitter (constant or envmap) is allowed per scene")
            if t == "constant":
                scene.environment = self.emitter_colour(node, path, props, "radiance")
            else:
                scene.envmap = self.envmap(node, path, props)
            return
        m = self.value(node, path, props, "to_world", TRANSFORM, None)
        if t == "point":
            pos = self.value(node, path, props, "position", POINT, None)
            if pos is not None and m is not None:
                self.fail(w("position"), 'give "position" or "to_world", not both')
            position = pos if pos is not None else (m[:3, 3].copy() if m is not None else np.zeros(3))
            scene.point_lights.append(PointLight(position=position,
                                                 intensity=self.emitter_colour(node, path, props, "intensity")))
        elif t == "spot":
            m = np.eye(4) if m is None else m
            lin = m[:3, :3]
            if np.max(np.abs(lin.T @ lin - np.eye(3))) > 1e-3:
                self.fail(w("to_world"), "a spot light's to_world may only rotate and translate")
            cutoff = self.value(node, path, props, "cutoff_angle", FLOAT, 20.0)
            self.in_range(w("cutoff_angle"), "cutoff_angle", cutoff, 0.0 < cutoff <= 90.0, "in (0, 90] degrees")
            beam = self.value(node, path, props, "beam_width", FLOAT, 0.75 * cutoff)
            self.in_range(w("beam_width"), "beam_width", beam, 0.0 <= beam < cutoff,
                          f"in [0, cutoff_angle = {cutoff}) degrees")
            scene.spot_lights.append(SpotLight(position=m[:3, 3].copy(), to_world=lin.copy(),
                                               intensity=self.emitter_colour(node, path, props, "intensity"),
                                               cutoff_angle=cutoff, beam_width=beam))
        else:  # directional
            direction = self.value(node, path, props, "direction", POINT, None)
            if direction is not None and m is not None:
                self.fail(w("direction"), 'give "direction" or "to_world", not both')
            if direction is None:
                direction = (np.eye(4) if m is None else m)[:3, :3] @ np.array([0.0, 0.0, 1.0])
            norm = float(np.linalg.norm(direction))
            if not norm > 0:
                self.fail(w("direction" if "direction" in props else "to_world"), "the direction must not be zero")
            scene.directional_lights.append(DirectionalLight(
                direction=np.asarray(direction, dtype=np.float64) / norm,
                irradiance=self.emitter_colour(node, path, props, "irradiance")))

    def integrator(self, node: Mapping, path: str) -> Integrator:
        spec = self.spec(node, path, ("integrator",))
        props, objs = self.fields(node, path, spec)
        w = lambda k: _prop_where(node, path, k)  # noqa: E731
        if node["type"] == "moment":
            return self.moment(node, path, objs)
        if node["type"] == "direct":
            return self.direct(node, path, props)
        max_depth = self.value(node, path, props, "max_depth", INT, -1)
        self.in_range(w("max_depth"), "max_depth", max_depth, max_depth >= -1, "-1 (unlimited) or >= 0")
        rr_depth = self.value(node, path, props, "rr_depth", INT, 5)
        self.in_range(w("rr_depth"), "rr_depth", rr_depth, rr_depth > 0, "> 0")
        hide = self.value(node, path, props, "hide_emitters", BOOL, False)
        return Integrator(max_depth=max_depth, rr_depth=rr_depth, hide_emitters=hide)

    def moment(self, node: Mapping, path: str, objs: list[_Obj]) -> Integrator:
        """Mitsuba's moment integrator: the nested integrator's image, plus its mean XYZ and per-sample second
        moment as layers named after it (its name, or "_arg_0" when it has none, as Mitsuba's parser)."""
        where = _where(node, path)
        if not objs:
            self.fail(where, "the moment integrator needs a nested integrator (path or direct)")
        if len(objs) > 1:
            self.fail(_where(objs[1].node, objs[1].path), "only one integrator inside moment is supported")
        inner = objs[0]
        if inner.node["type"] == "moment":
            self.fail(_where(inner.node, inner.path), "a moment integrator cannot nest another moment integrator")
        name = next(k for k, v in node.items() if k not in ("type", "id") and _is_plugin(v))  # (the only one)
        return dataclasses.replace(self.integrator(inner.node, inner.path), moment=name)

    def direct(self, node: Mapping, path: str, props: dict) -> Integrator:
        """Mitsuba's direct illumination integrator, as path tracing with max_depth 2."""
        w = lambda k: _prop_where(node, path, k)  # noqa: E731
        if "shading_samples" in props and ("emitter_samples" in props or "bsdf_samples" in props):
            self.fail(w("shading_samples"), "give shading_samples or emitter_samples and bsdf_samples, not both")
        n = self.value(node, path, props, "shading_samples", INT, 1)
        self.in_range(w("shading_samples"), "shading_samples", n, n > 0, "> 0")
        n_e = self.value(node, path, props, "emitter_samples", INT, n)
        n_b = self.value(node, path, props, "bsdf_samples", INT, n)
        # with none of one kind, Mitsuba drops whole kinds of paths (point lights, or emitters seen in mirrors)
        self.in_range(w("emitter_samples"), "emitter_samples", n_e, n_e > 0, "> 0")
        self.in_range(w("bsdf_samples"), "bsdf_samples", n_b, n_b > 0, "> 0")
        if self.value(node, path, props, "hide_emitters", BOOL, False):
            self.fail(w("hide_emitters"), "hide_emitters=true is not supported for direct (Mitsuba's direct then "
                                          "looks through area emitters at what is behind them)")
        return Integrator(max_depth=2, kind="direct", light_samples=n_e)

    def sensor(self, node: Mapping, path: str) -> Scene:
        spec = self.spec(node, path, ("sensor",))
        props, objs = self.fields(node, path, spec)
        where = _where(node, path)
        w = lambda k: _prop_where(node, path, k)  # noqa: E731
        fov, fov_axis = self.field_of_view(node, path, props)
        near = self.value(node, path, props, "near_clip", FLOAT, 1e-2)
        self.in_range(w("near_clip"), "near_clip", near, near > 0, "> 0")
        far = self.value(node, path, props, "far_clip", FLOAT, 1e4)
        self.in_range(w("far_clip"), "far_clip", far, far > near, f"> near_clip ({near})")
        # Mitsuba reads focus_distance on every projective camera (a pinhole ignores it); default far_clip
        focus = self.value(node, path, props, "focus_distance", FLOAT, far)
        self.in_range(w("focus_distance"), "focus_distance", focus, focus > 0, "> 0")
        for key in ("principal_point_offset_x", "principal_point_offset_y"):
            v = self.value(node, path, props, key, FLOAT, 0.0)
            if v != 0.0:
                self.fail(w(key), f"{key} other than 0 (an off-centre projection) is not supported")
        t_open = self.value(node, path, props, "shutter_open", FLOAT, 0.0)
        t_close = self.value(node, path, props, "shutter_close", FLOAT, 0.0)
        self.in_range(w("shutter_close"), "shutter_close", t_close, t_close >= t_open,
                      f">= shutter_open ({t_open}); nothing moves, so the shutter changes nothing")
        aperture = 0.0
        if node["type"] == "thinlens":
            if "aperture_radius" not in props:
                self.fail(where, 'the thinlens sensor needs "aperture_radius" (the lens radius, in world units)')
            aperture = self.value(node, path, props, "aperture_radius", FLOAT)
            self.in_range(w("aperture_radius"), "aperture_radius", aperture, aperture >= 0, ">= 0")
            aperture = max(aperture, 2.0**-24)  # Mitsuba: 0 warns and becomes its Epsilon
        m = self.value(node, path, props, "to_world", TRANSFORM, np.eye(4))
        lin = m[:3, :3]
        if np.max(np.abs(lin.T @ lin - np.eye(3))) > 1e-3:
            self.fail(w("to_world"), "the sensor's to_world may only rotate and translate "
                                     "(scale factors are not allowed, as in Mitsuba)")
        camera = Camera(to_world=m, fov=fov, fov_axis=fov_axis, near_clip=near, far_clip=far,
                        aperture_radius=aperture, focus_distance=focus)
        scene = Scene(camera=camera, rfilter=PixelFilter.gaussian())  # Mitsuba's film and filter by default

        sampler = self.one(objs, "sampler", where)
        if sampler is not None:
            s_spec = self.spec(sampler.node, sampler.path, ("sampler",))
            s_props, _ = self.fields(sampler.node, sampler.path, s_spec)
            sw = lambda k: _prop_where(sampler.node, sampler.path, k)  # noqa: E731
            spp = self.value(sampler.node, sampler.path, s_props, "sample_count", INT, 4)
            scene.spp = self.in_range(sw("sample_count"), "sample_count", spp, 0 < spp <= UINT32_MAX,
                                      f"in [1, {UINT32_MAX}]")
            seed = self.value(sampler.node, sampler.path, s_props, "seed", INT, 0)
            scene.sampler_seed = self.in_range(sw("seed"), "seed", seed, 0 <= seed <= UINT32_MAX,
                                               f"in [0, {UINT32_MAX}]")

        film = self.one(objs, "film", where)
        if film is not None:
            f_spec = self.spec(film.node, film.path, ("film",))
            f_props, f_objs = self.fields(film.node, film.path, f_spec)
            fw = lambda k: _prop_where(film.node, film.path, k)  # noqa: E731
            for key in ("width", "height"):
                v = self.value(film.node, film.path, f_props, key, INT, getattr(scene, key))
                setattr(scene, key, self.in_range(fw(key), key, v, 0 < v <= UINT32_MAX, f"in [1, {UINT32_MAX}]"))
            pf = self.value(film.node, film.path, f_props, "pixel_format", STRING, "rgb")
            if pf != "rgb":
                self.fail(fw("pixel_format"), f'pixel_format "{pf}" is not supported (supported: rgb)')
            cf = self.value(film.node, film.path, f_props, "component_format", STRING, "float16")
            if cf not in ("float16", "float32"):
                self.fail(fw("component_format"), f'component_format "{cf}" is not supported '
                                                  f"(supported: float16, float32)")
            ff = self.value(film.node, film.path, f_props, "file_format", STRING, "openexr")
            if ff not in ("openexr", "exr", "rgbe", "pfm"):
                self.fail(fw("file_format"), f'file_format "{ff}" is not one of openexr, exr, rgbe, pfm')
            # file_format, banner and compensate only change Mitsuba's own output file: ours is named by -o
            self.value(film.node, film.path, f_props, "banner", BOOL, True)
            self.value(film.node, film.path, f_props, "compensate", BOOL, False)
            scene.sample_border = self.value(film.node, film.path, f_props, "sample_border", BOOL, False)
            crop = [self.value(film.node, film.path, f_props, k, INT, d) for k, d in
                    (("crop_offset_x", 0), ("crop_offset_y", 0), ("crop_width", scene.width),
                     ("crop_height", scene.height))]
            if crop != [0, 0, scene.width, scene.height]:
                key = next(k for k in ("crop_offset_x", "crop_offset_y", "crop_width", "crop_height") if k in f_props)
                self.fail(fw(key), "a crop window other than the whole film is not supported")
            rfilter = self.one(f_objs, "rfilter", _where(film.node, film.path))
            if rfilter is not None:
                scene.rfilter = self.rfilter(rfilter.node, rfilter.path)
        return scene

    def field_of_view(self, node: Mapping, path: str, props: dict) -> tuple[float, str]:
        """(fov in degrees, its axis), as Mitsuba's parse_fov: ``fov`` along ``fov_axis``, or ``focal_length`` (a
        string in mm, default "50mm") as the diagonal field of view of a 36 x 24 mm film."""
        w = lambda k: _prop_where(node, path, k)  # noqa: E731
        if "fov" in props and "focal_length" in props:
            self.fail(w("focal_length"), 'give "fov" or "focal_length", not both')
        if "fov" in props:
            fov = self.value(node, path, props, "fov", FLOAT)
            self.in_range(w("fov"), "fov", fov, 0.0 < fov < 180.0, "in (0, 180) degrees")
            fov_axis = self.value(node, path, props, "fov_axis", STRING, "x").lower()
            if fov_axis not in FOV_AXES:
                self.fail(w("fov_axis"), f'fov_axis "{fov_axis}" is not one of {", ".join(FOV_AXES)}')
            return fov, fov_axis
        if "fov_axis" in props:
            self.fail(w("fov_axis"), 'fov_axis applies to "fov" only (a focal_length is always diagonal)')
        text = self.value(node, path, props, "focal_length", STRING, "50mm")
        number = text[:-2] if text.endswith("mm") else text
        try:
            f = float(number)
        except ValueError:
            f = float("nan")
        if not (np.isfinite(f) and f > 0):
            self.fail(w("focal_length"), f'focal_length "{text}" must be a positive length in mm (e.g. "50mm")')
        return float(np.degrees(2.0 * np.arctan(np.hypot(36.0, 24.0) / (2.0 * f)))), "diagonal"

    def rfilter(self, node: Mapping, path: str) -> PixelFilter:
        spec = self.spec(node, path, ("rfilter",))
        props, _ = self.fields(node, path, spec)
        t = node["type"]
        if t == "box":
            return PixelFilter("box")
        key, default = ("radius", 1.0) if t == "tent" else ("stddev", 0.5)
        v = self.value(node, path, props, key, FLOAT, default)
        # a filter wider than 64 pixels is almost certainly a unit mistake (and a huge splat in Mitsuba)
        self.in_range(_prop_where(node, path, key), key, v, 0.0 < v <= 64.0, "in (0, 64] pixels")
        return PixelFilter("tent", v) if t == "tent" else PixelFilter.gaussian(v)

    def material(self, node: Mapping, path: str) -> Material:
        key = id(node)
        if key in self.materials:
            return self.materials[key]
        if key in self.visiting:
            self.fail(_where(node, path), "a bsdf cannot contain itself")
        self.visiting.add(key)
        spec = self.spec(node, path, ("bsdf",))
        props, objs = self.fields(node, path, spec)
        t = node["type"]
        w = lambda k: _prop_where(node, path, k)  # noqa: E731
        if t == "twosided":
            if not objs:
                self.fail(_where(node, path), "twosided needs one nested bsdf")
            if len(objs) > 1:
                self.fail(_where(objs[1].node, objs[1].path), "twosided with two different bsdfs (front and back) "
                                                              "is not supported: give one")
            inner = self.material(objs[0].node, objs[0].path)
            if inner.twosided:
                self.fail(_where(objs[0].node, objs[0].path), "a twosided bsdf cannot be nested in a twosided bsdf")
            mat = dataclasses.replace(inner, twosided=True)
        elif t == "diffuse":
            rgb, tex = self.colour_slot(node, path, props, "reflectance", (0.5, 0.5, 0.5))
            mat = Material("diffuse", self.reflectance(w("reflectance"), "reflectance", rgb), texture=tex)
        elif t in ("dielectric", "thindielectric", "plastic", "roughplastic"):
            plastic = t in ("plastic", "roughplastic")
            int_ior = self.value(node, path, props, "int_ior", IOR, IOR_TABLE["polypropylene" if plastic else "bk7"])
            ext_ior = self.value(node, path, props, "ext_ior", IOR, IOR_TABLE["air"])
            if plastic and int_ior == ext_ior:
                self.fail(w("int_ior"), f"{t} needs int_ior and ext_ior to differ (Mitsuba refuses equal ones)")
            eta = (int_ior / ext_ior,) * 3
            if plastic:
                spec = self.reflectance(w("specular_reflectance"), "specular_reflectance",
                                        self.value(node, path, props, "specular_reflectance", COLOR, (1.0, 1.0, 1.0)))
                diffuse, tex = self.colour_slot(node, path, props, "diffuse_reflectance", (0.5, 0.5, 0.5))
                diffuse = self.reflectance(w("diffuse_reflectance"), "diffuse_reflectance", diffuse)
                nonlinear = self.value(node, path, props, "nonlinear", BOOL, False)
                if t == "plastic":
                    mat = Material("plastic", diffuse, rgb2=spec, eta=eta, nonlinear=nonlinear, texture=tex)
                else:
                    dist = self.value(node, path, props, "distribution", STRING, "beckmann")
                    if dist not in ("beckmann", "ggx"):
                        self.fail(w("distribution"), f'unknown distribution "{dist}" (supported: beckmann, ggx)')
                    self.value(node, path, props, "sample_visible", BOOL, True)
                    alpha = self.value(node, path, props, "alpha", FLOAT, 0.1)
                    self.in_range(w("alpha"), "alpha", alpha, alpha >= 0.0, ">= 0")
                    mat = Material("roughplastic", diffuse, rgb2=spec, eta=eta, nonlinear=nonlinear, texture=tex,
                                   alpha=max(alpha, 1.0e-4), distribution=dist)
            else:
                spec, tex = self.colour_slot(node, path, props, "specular_reflectance", (1.0, 1.0, 1.0))
                spec = self.reflectance(w("specular_reflectance"), "specular_reflectance", spec)
                trans = self.reflectance(w("specular_transmittance"), "specular_transmittance", self.value(
                    node, path, props, "specular_transmittance", COLOR, (1.0, 1.0, 1.0)))
                mat = Material(t, spec, rgb2=trans, eta=eta, texture=tex)
        else:  # conductor, roughconductor
            eta, k = self.complex_ior(node, path, props)
            rgb, tex = self.colour_slot(node, path, props, "specular_reflectance", (1.0, 1.0, 1.0))
            rgb = self.reflectance(w("specular_reflectance"), "specular_reflectance", rgb)
            if t == "conductor":
                if eta == (0.0, 0.0, 0.0) and k == (1.0, 1.0, 1.0) and tex < 0:
                    mat = Material("mirror", rgb)  # Fresnel reflectance 1 at every angle
                else:
                    mat = Material("conductor", rgb, eta=eta, k=k, texture=tex)
            else:
                dist = self.value(node, path, props, "distribution", STRING, "beckmann")
                if dist not in ("beckmann", "ggx"):
                    self.fail(w("distribution"), f'unknown distribution "{dist}" (supported: beckmann, ggx)')
                alpha = self.roughness(node, path, props)
                mat = Material("roughconductor", rgb, eta=eta, k=k, alpha=alpha, distribution=dist, texture=tex)
        if self.node_ids.get(id(node)):  # its parameters' names (pathtracer/gradients.py)
            mat = dataclasses.replace(mat, name=self.node_ids[id(node)])
        self.visiting.discard(key)
        self.materials[key] = mat
        return mat

    def colour_slot(self, node: Mapping, path: str, props: dict, key: str, default: tuple) -> tuple[tuple, int]:
        """A reflectance that may be a texture: (its rgb, or a texture's mean; the index in the scene's textures
        or -1)."""
        v = props.get(key)
        where = _prop_where(node, path, key)
        if _is_plugin(v) and v["type"] == "ref":
            v, _ = self.resolve(v, where)
        if not (_is_plugin(v) and _category(v) == "texture"):
            return self.value(node, path, props, key, COLOR, default), -1
        tex = self.texture(v, f"{path}[{key!r}]")
        for i, t in enumerate(self.textures):
            if t is tex:
                return tex.mean(), i
        self.textures.append(tex)
        return tex.mean(), len(self.textures) - 1

    def texture(self, node: Mapping, path: str) -> Texture:
        key = id(node)
        if key in self.texture_nodes:
            return self.texture_nodes[key]
        spec = self.spec(node, path, ("texture",))
        props, _ = self.fields(node, path, spec)
        w = lambda k: _prop_where(node, path, k)  # noqa: E731
        m = self.value(node, path, props, "to_uv", TRANSFORM, np.eye(4))
        # Mitsuba keeps the 2D part of a 4x4 to_uv: x and y rows and columns, and the translation
        to_uv = np.array([[m[0, 0], m[0, 1], m[0, 3]], [m[1, 0], m[1, 1], m[1, 3]]])
        if node["type"] == "checkerboard":
            c0 = self.value(node, path, props, "color0", COLOR, (0.4, 0.4, 0.4))
            c1 = self.value(node, path, props, "color1", COLOR, (0.2, 0.2, 0.2))
            tex = Texture("checkerboard", to_uv=to_uv, color0=self.reflectance(w("color0"), "color0", c0),
                          color1=self.reflectance(w("color1"), "color1", c1))
        else:
            filename = self.value(node, path, props, "filename", STRING)
            if filename is None:
                self.fail(_where(node, path), 'bitmap needs "filename"')
            filt = self.value(node, path, props, "filter_type", STRING, "bilinear")
            if filt not in ("bilinear", "nearest"):
                self.fail(w("filter_type"), f'unknown filter_type "{filt}" (supported: bilinear, nearest)')
            wrap = self.value(node, path, props, "wrap_mode", STRING, "repeat")
            if wrap not in ("repeat", "mirror", "clamp"):
                self.fail(w("wrap_mode"), f'unknown wrap_mode "{wrap}" (supported: repeat, mirror, clamp)')
            if self.value(node, path, props, "raw", BOOL, False):
                self.fail(w("raw"), "raw=true is not supported (8-bit images are read as sRGB, as Mitsuba's default)")
            fmt = self.value(node, path, props, "format", STRING, "auto")
            if fmt not in ("auto", "variant", "float16", "uint8"):
                self.fail(w("format"), f'unknown format "{fmt}" (supported: auto, variant, float16, uint8)')
            self.value(node, path, props, "accel", BOOL, True)
            if os.path.splitext(filename)[1].lower() not in imageio.READ_EXTENSIONS:
                self.fail(w("filename"), f'bitmap "{filename}": only OpenEXR (.exr), Radiance HDR (.hdr), PNG '
                                         f'and JPEG images are supported')
            file = resolve_file(filename, self.search_paths)
            try:
                img = imageio.read_image(file)
            except ImageIOError as e:
                self.fail(w("filename"), f'bitmap "{filename}": {str(e).split(": ", 1)[-1]}')
            if not np.all(np.isfinite(img)) or img.min() < 0 or img.max() > 1:
                self.fail(w("filename"), f'bitmap "{filename}": a reflectance texture must lie in [0, 1]')
            tex = Texture("bitmap", to_uv=to_uv, image=img, filter=filt, wrap=wrap, filename=str(file))
        self.texture_nodes[key] = tex
        return tex

    def complex_ior(self, node: Mapping, path: str, props: dict) -> tuple[tuple, tuple]:
        """A conductor's (eta, k) per channel: from its named material, or eta (0) and k (1) as Mitsuba."""
        w = lambda k: _prop_where(node, path, k)  # noqa: E731
        name = self.value(node, path, props, "material", STRING, "none")
        if "eta" in props or "k" in props or name == "none":
            if name != "none":
                self.fail(w("material"), "give either a material or eta and k, not both (as Mitsuba)")
            for key in ("eta", "k"):
                if key in props and _is_plugin(props[key]) and props[key]["type"] == "spectrum":
                    self.fail(w(key), f"{key} as a spectrum is not supported (give rgb values or a named material)")
            eta = self.value(node, path, props, "eta", COLOR, (0.0, 0.0, 0.0))
            k = self.value(node, path, props, "k", COLOR, (1.0, 1.0, 1.0))
            for key, v in (("eta", eta), ("k", k)):
                self.in_range(w(key), key, list(v), min(v) >= 0.0, ">= 0 in every channel")
            return tuple(eta), tuple(k)
        if name not in CONDUCTOR_RGB:
            close = [n for n in CONDUCTOR_RGB if n.lower() == name.lower()]
            hint = f' (did you mean "{close[0]}"?)' if close else ""
            self.fail(w("material"), f'unknown conductor material "{name}"{hint} (known: '
                                     f'{", ".join(n for n in CONDUCTOR_RGB if not n.endswith("_palik"))}, ...)')
        eta, k = CONDUCTOR_RGB[name]
        return tuple(float(x) for x in eta), tuple(float(x) for x in k)

    def roughness(self, node: Mapping, path: str, props: dict) -> float:
        """An isotropic microfacet alpha (0.1 by default)."""
        w = lambda k: _prop_where(node, path, k)  # noqa: E731
        if "alpha" in props and ("alpha_u" in props or "alpha_v" in props):
            self.fail(w("alpha"), "give alpha or alpha_u and alpha_v, not both")
        if "alpha_u" in props or "alpha_v" in props:
            if "alpha_u" not in props or "alpha_v" not in props:
                self.fail(w("alpha_u" if "alpha_u" in props else "alpha_v"), "alpha_u and alpha_v go together")
            au = self.value(node, path, props, "alpha_u", FLOAT)
            av = self.value(node, path, props, "alpha_v", FLOAT)
            if au != av:
                self.fail(w("alpha_u"), f"anisotropic roughness (alpha_u {au} != alpha_v {av}) is not supported")
            key, alpha = "alpha_u", au
        else:
            key, alpha = "alpha", self.value(node, path, props, "alpha", FLOAT, 0.1)
        self.in_range(w(key), key, alpha, alpha >= 0.0, ">= 0")
        return max(alpha, 1.0e-4)  # Mitsuba's floor

    def reflectance(self, where: str, key: str, rgb: tuple) -> tuple:
        if not all(0.0 <= c <= 1.0 for c in rgb):
            self.fail(where, f"{key} must lie in [0, 1] (got {list(rgb)})")
        return rgb

    def shape(self, node: Mapping, path: str, key, scene: Scene):
        spec = self.spec(node, path, ("shape",))
        props, objs = self.fields(node, path, spec)
        where = _where(node, path)
        t = node["type"]
        w = lambda k: _prop_where(node, path, k)  # noqa: E731
        flip_normals = self.value(node, path, props, "flip_normals", BOOL, False)
        if flip_normals and t not in ("disk", "cylinder"):
            self.fail(w("flip_normals"), f"flip_normals=true is not supported on a {t} (turn the shape with "
                                         f"to_world)")
        m = self.value(node, path, props, "to_world", TRANSFORM, np.eye(4))
        bsdf = self.one(objs, "bsdf", where)
        emitter = self.one(objs, "emitter", where)

        radiance = None
        if emitter is not None:
            e_spec = self.spec(emitter.node, emitter.path, ("emitter",))
            if emitter.node["type"] != "area":
                self.fail(_where(emitter.node, emitter.path), f'a shape can only hold an area emitter (a '
                                                              f'{emitter.node["type"]} emitter goes at scene level)')
            if id(emitter.node) in self.attached:
                self.fail(_where(emitter.node, emitter.path), "an area emitter can be attached to one shape only "
                                                              "(as in Mitsuba)")
            self.attached.add(id(emitter.node))
            e_props, _ = self.fields(emitter.node, emitter.path, e_spec)
            radiance = self.emitter_colour(emitter.node, emitter.path, e_props, "radiance")
        if bsdf is not None:
            material = self.material(bsdf.node, bsdf.path)
            shape_id = node.get("id") if isinstance(node.get("id"), str) else None
            if shape_id is None and not (isinstance(node, XmlDict) or str(key).startswith("_arg_")):
                shape_id = str(key)
            if not material.name and shape_id:  # Mitsuba names a nested bsdf's parameters "<shape>.bsdf.*"
                material = dataclasses.replace(material, name=f"{shape_id}.bsdf")
        elif emitter is not None:
            material = Material("diffuse", (0.0, 0.0, 0.0))  # Mitsuba: an emitter's default bsdf is black
        else:
            material = DEFAULT_MATERIAL
        mat_index = scene.add_material(material)
        scene.textures = self.textures
        if material.texture >= 0 and t in ("disk", "cylinder"):
            self.fail(where, f"a textured bsdf on a {t} is not supported yet (textures work on spheres, "
                             f"rectangles, cubes and obj, ply and serialized meshes)")
        name = node.get("id") if isinstance(node.get("id"), str) else None
        if name is None:
            name = str(key) if not (isinstance(node, XmlDict) or str(key).startswith("_arg_")) else t

        lin = m[:3, :3]
        if t == "sphere":
            center = self.value(node, path, props, "center", POINT, np.zeros(3))
            radius = self.value(node, path, props, "radius", FLOAT, 1.0)
            self.in_range(w("radius"), "radius", radius, radius > 0, "> 0")
            # Mitsuba: to_world @ translate(center) @ scale(radius); to_world must be a similarity.
            s2 = float(np.mean(np.sum(lin * lin, axis=0)))
            if not (s2 > 0 and np.max(np.abs(lin.T @ lin / s2 - np.eye(3))) <= 1e-6):
                self.fail(w("to_world"), "a sphere's to_world may only translate, rotate and scale uniformly")
            if np.linalg.det(lin) < 0:
                self.fail(w("to_world"), "a sphere's to_world must not mirror (Mitsuba would turn its normals "
                                         "inwards)")
            scale = 1.0 if s2 == 1.0 else float(np.sqrt(s2))
            sphere = Sphere(center=tf.transform_points(m, center), radius=scale * radius, material=mat_index,
                            rotation=lin / scale)
            if not (np.all(np.isfinite(sphere.center)) and np.isfinite(sphere.radius)):
                self.fail(where, "the sphere's centre or radius overflows (not finite)")
            scene.spheres.append(sphere)
            if radiance is not None:
                scene.sphere_lights.append(SphereLight(sphere=len(scene.spheres) - 1, radiance=radiance))
            return

        if not _check_invertible(lin):
            self.fail(w("to_world"), "to_world is singular (a zero scale flattens the shape)")
        flip = np.linalg.det(lin) < 0
        if t in ("rectangle", "cube"):
            base_v, base_f = (_RECT_VERTICES, np.array([[0, 1, 2], [0, 2, 3]])) if t == "rectangle" else \
                (_CUBE_VERTICES, _CUBE_FACES)
            vertices = tf.transform_points(m, base_v)
            faces = base_f[:, [0, 2, 1]] if flip else base_f.copy()
            normals = None
        elif t in ("disk", "cylinder"):
            vertices, faces, normals, m = self.tessellated(node, path, props, m, flip_normals)
        else:
            vertices, faces, normals, file_uv = self.mesh_file(node, path, props, m, flip, material.texture >= 0)
        if not np.all(np.isfinite(vertices)) or (normals is not None and not np.all(np.isfinite(normals))):
            self.fail(where, "to_world makes vertex positions or normals overflow (not finite)")
        # an emitting cube stays triangles: a mesh light (its faces are not one parallelogram light each)
        kind = t if t == "rectangle" or (t == "cube" and radiance is None) else "mesh"
        uvs = None
        if t == "rectangle":
            uvs = 0.5 * (_RECT_VERTICES[:, :2] + 1.0)  # Mitsuba's: ((x + 1) / 2, (y + 1) / 2)
        elif t == "cube":
            uvs = np.tile([[0.0, 1.0], [1.0, 1.0], [1.0, 0.0], [0.0, 0.0]], (6, 1))  # each face onto [0, 1]^2
        elif t in ("obj", "ply", "serialized"):
            uvs = file_uv
        mesh = TriangleMesh(vertices=vertices, faces=np.asarray(faces, dtype=np.int64), normals=normals,
                            material=mat_index, name=name, shape=kind, uvs=uvs)
        if radiance is not None and t != "rectangle":
            scene.mesh_lights.append(MeshLight(mesh=len(scene.meshes), radiance=radiance))
        elif radiance is not None:
            normal = tf.normal_matrix(m) @ np.array([0.0, 0.0, 1.0])
            scene.lights.append(RectLight(center=m[:3, 3].copy(), half_u=lin[:, 0].copy(), half_v=lin[:, 1].copy(),
                                          normal=normal / np.linalg.norm(normal), radiance=radiance))
            mesh.light = len(scene.lights) - 1
        scene.meshes.append(mesh)

    def tessellated(self, node: Mapping, path: str, props: dict, m: np.ndarray, flip_normals: bool):
        """Mitsuba's disk or cylinder as a fine mesh (pathtracer/tessellate.py): world vertices, faces wound so
        that their normal is Mitsuba's, vertex normals (None: flat) and the shape's full to_world."""
        w = lambda k: _prop_where(node, path, k)  # noqa: E731
        if node["type"] == "disk":
            local_v, faces = tessellate.disk()
            local_n = None
        else:
            p0 = self.value(node, path, props, "p0", POINT, np.zeros(3))
            p1 = self.value(node, path, props, "p1", POINT, np.array([0.0, 0.0, 1.0]))
            radius = self.value(node, path, props, "radius", FLOAT, 1.0)
            self.in_range(w("radius"), "radius", radius, radius > 0, "> 0")
            axis = np.asarray(p1, dtype=np.float64) - np.asarray(p0, dtype=np.float64)
            length = float(np.linalg.norm(axis))
            if not length > 0:
                self.fail(w("p1"), "a cylinder's p0 and p1 must differ")
            # Mitsuba: to_world @ translate(p0) @ to_frame(axis) @ scale(radius, radius, length)
            z = axis / length
            x = np.cross(z, [1.0, 0.0, 0.0] if abs(z[0]) < 0.9 else [0.0, 1.0, 0.0])
            x /= np.linalg.norm(x)
            frame = np.eye(4)
            frame[:3, :3] = np.stack([x, np.cross(z, x), z], axis=1)
            frame[:3, 3] = p0
            m = m @ frame @ np.diag([radius, radius, length, 1.0])
            local_v, faces, local_n = tessellate.cylinder()
        lin = m[:3, :3]
        if not _check_invertible(lin):
            self.fail(w("to_world"), "to_world is singular (a zero scale flattens the shape)")
        if flip_normals:  # Mitsuba turns the normals to the other side
            faces = faces[:, [0, 2, 1]]
            local_n = None if local_n is None else -local_n
        if np.linalg.det(lin) < 0:  # a mirroring to_world reverses the winding, not the (normal-transformed) normal
            faces = faces[:, [0, 2, 1]]
        vertices = tf.transform_points(m, local_v)
        normals = None if local_n is None else tf.transform_normals(m, local_n)
        return vertices, faces, normals, m

    def envmap(self, node: Mapping, path: str, props: dict) -> EnvMap:
        w = lambda k: _prop_where(node, path, k)  # noqa: E731
        filename = self.value(node, path, props, "filename", STRING)
        if filename is None:
            self.fail(_where(node, path), 'envmap needs "filename"')
        scale = self.value(node, path, props, "scale", FLOAT, 1.0)
        self.in_range(w("scale"), "scale", scale, scale >= 0.0, ">= 0")
        self.value(node, path, props, "mis_compensation", BOOL, False)
        m = self.value(node, path, props, "to_world", TRANSFORM, np.eye(4))
        lin = m[:3, :3]
        if np.max(np.abs(lin.T @ lin - np.eye(3))) > 1e-3 or np.linalg.det(lin) < 0:
            self.fail(w("to_world"), "an envmap's to_world may only rotate (Mitsuba maps unnormalised directions)")
        if os.path.splitext(filename)[1].lower() not in (".exr", ".hdr", ".rgbe", ".png"):
            self.fail(w("filename"), f'envmap "{filename}": only OpenEXR (.exr), Radiance HDR (.hdr) and PNG maps '
                                     f'are supported')
        file = resolve_file(filename, self.search_paths)
        try:
            img = imageio.read_image(file)
        except ImageIOError as e:
            self.fail(w("filename"), f'envmap "{filename}": {str(e).split(": ", 1)[-1]}')
        if img.shape[0] < 2 or img.shape[1] < 1:
            self.fail(w("filename"), f'envmap "{filename}" must be at least 1 x 2 pixels (got {img.shape[1]} x '
                                     f'{img.shape[0]})')
        if not np.all(np.isfinite(img)) or img.min() < 0:
            self.fail(w("filename"), f'envmap "{filename}" has negative, NaN or infinite pixels')
        return EnvMap(image=img, to_world=lin.copy(), scale=scale, filename=str(file))

    def mesh_file(self, node: Mapping, path: str, props: dict, m: np.ndarray, flip: bool, need_uv: bool):
        where = _where(node, path)
        filename = self.value(node, path, props, "filename", STRING)
        if filename is None:
            self.fail(where, f'{node["type"]} needs "filename"')
        face_normals = self.value(node, path, props, "face_normals", BOOL, False)
        # Mitsuba 3.9: OBJ texture coordinates are flipped (v -> 1 - v) by default, PLY ones not, serialized never
        flip_uv = node["type"] != "serialized" and self.value(node, path, props, "flip_tex_coords", BOOL,
                                                               node["type"] == "obj")
        file = resolve_file(filename, self.search_paths)
        try:
            if node["type"] == "serialized":
                index = self.value(node, path, props, "shape_index", INT, 0)
                self.in_range(_prop_where(node, path, "shape_index"), "shape_index", index, index >= 0, ">= 0")
                parts = [meshio.read_serialized(file, index)]
            else:
                parts = meshio.read_mesh(file, node["type"])
        except meshio.MeshFileError as e:
            self.fail(where, f'mesh file "{filename}" {e}')
        # Mitsuba keeps the file as one mesh: where some vertices have texture coordinates, the others get 0;
        # where none has any, uv is the barycentric (b1, b2) of each face (a uv per corner: see below)
        any_uv = any(p.uv is not None for p in parts)
        vs, fs, ns, uvs, offset = [], [], [], [], 0
        for p in parts:
            v = tf.transform_points(m, p.vertices)
            f = p.faces
            order = [0, 1, 2]  # our corners' places in the file's faces
            if face_normals:
                n = None
            elif p.normals is not None:
                n = tf.transform_normals(m, p.normals)
                if flip:  # keep the file's winding relative to its normals (Mitsuba shades by the normals)
                    order = [0, 2, 1]
                    f = f[:, order]
            else:
                n = meshio.vertex_normals(v, f)
            uv = None
            if p.uv is not None:
                uv = np.column_stack([p.uv[:, 0], 1.0 - p.uv[:, 1]]) if flip_uv else p.uv
            elif any_uv:
                uv = np.zeros((len(v), 2))
            elif need_uv:  # each face gets its own three vertices (same positions and normals, so same surface)
                flat = f.reshape(-1)
                v, n = v[flat], (None if n is None else n[flat])
                f = np.arange(len(flat), dtype=np.int64).reshape(-1, 3)
                uv = np.tile(np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])[order], (len(p.faces), 1))
            vs.append(v)
            fs.append(f + offset if offset else f)
            ns.append(n)
            uvs.append(uv)
            offset += len(v)
        normals = None if face_normals else meshio.join_arrays(ns)
        uv = meshio.join_arrays(uvs) if uvs[0] is not None else None
        return meshio.join_arrays(vs), meshio.join_arrays(fs), normals, uv
