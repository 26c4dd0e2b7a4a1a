"""Structs that carry the scene, the camera and one pass's parameters into the kernels."""

import warp as wp


@wp.struct
class CameraData:
    """Pinhole camera: local +z forward, local +x image left (Mitsuba's convention)."""

    origin: wp.vec3
    to_world: wp.mat33  # local -> world, linear part of the sensor's to_world
    to_local: wp.mat33  # its inverse (world -> local directions), for projecting points onto the film
    tan_x: float  # tan(half fov) along image x
    tan_y: float
    near_clip: float
    far_clip: float
    width: int
    height: int
    filter_cdf: wp.array(dtype=float)  # the reconstruction filter's CDF table (kernels/film.py), empty for box
    filter_radius: float
    filter_border: int  # pixels sampled beyond the film's edges (Mitsuba's sample_border), 0 when not
    aperture_radius: float  # thin lens only
    focus_distance: float


@wp.struct
class SceneData:
    """Every primitive of a scene. Arrays of absent kinds are empty (their code is compiled out)."""

    # 4-wide box tree over every triangle's padded box (pathtracer/bvh.py WideTree; traversed in kernels/triangle.py)
    bvh_boxes: wp.array(dtype=wp.vec4)  # 6 per node: lower x, upper x, lower y, ... of its four children
    bvh_child: wp.array(dtype=wp.vec4i)  # child references: inner node >= 0, leaf < 0 (bvh.leaf_ref)
    bvh_root: int  # a reference too
    tri_soa: wp.array(dtype=wp.vec4)  # 9 per leaf block: corner c's axis a of its four triangles at 3 c + a (NaN: unused)
    tri_face: wp.array(dtype=wp.int32)  # 4 per leaf block: the face in each lane, -1 unused
    mesh_id: wp.uint64  # the wp.Mesh of the "warp" triangle backend (kernels/triangle_warp.py), 0 otherwise
    points: wp.array(dtype=wp.vec3)
    indices: wp.array(dtype=wp.int32)  # 3 per face
    face_material: wp.array(dtype=wp.int32)
    face_light: wp.array(dtype=wp.int32)  # area light index, -1 if the face does not emit
    corner_normals: wp.array(dtype=wp.vec3)  # 3 per face: shading normals, the face normal on flat faces
    corner_uv: wp.array(dtype=wp.vec2)  # 3 per face: texture coordinates (with textures only, else empty)
    sphere_center: wp.array(dtype=wp.vec3)
    sphere_radius: wp.array(dtype=float)
    sphere_material: wp.array(dtype=wp.int32)
    sphere_to_local: wp.array(dtype=wp.mat33)  # world -> the sphere's object frame (for texture coordinates)
    num_spheres: int
    quad_center: wp.array(dtype=wp.vec3d)  # analytic parallelograms (kernels/quad.py), float64
    quad_normal: wp.array(dtype=wp.vec3d)  # unit, the winding normal of the triangles the quad stands for
    quad_half_u: wp.array(dtype=wp.vec3d)
    quad_half_v: wp.array(dtype=wp.vec3d)
    quad_ustar: wp.array(dtype=wp.vec3d)  # dual basis: s = (p - center) . ustar
    quad_vstar: wp.array(dtype=wp.vec3d)
    quad_dual_len: wp.array(dtype=wp.vec2d)  # (|ustar|, |vstar|): ray_quad's edge tolerance
    quad_inside: wp.array(dtype=wp.vec2d)  # bounds on |s|, |r| of a hit record (kernels/quad.py: quad_hit)
    quad_scale: wp.array(dtype=float)  # largest absolute corner coordinate (for ray offsets)
    quad_material: wp.array(dtype=wp.int32)
    quad_light: wp.array(dtype=wp.int32)  # area light index, -1 if the quad does not emit
    quad_uv: wp.array(dtype=wp.vec2)  # 3 per quad: uv = [0] + s [1] + r [2] (kernels/textures.py)
    num_quads: int
    quad_group_end: wp.array(dtype=wp.int32)  # > i: quad i starts a boxed group (one shape) ending before this
    quad_box_lo: wp.array(dtype=wp.vec3d)  # that group's bounding box, padded (set at group starts only)
    quad_box_hi: wp.array(dtype=wp.vec3d)
    mat_kind: wp.array(dtype=wp.int32)  # pathtracer.scene.MATERIAL_KINDS
    mat_rgb: wp.array(dtype=wp.vec3)  # reflectance: diffuse (diffuse, plastic) or specular (the others)
    mat_twosided: wp.array(dtype=wp.int32)  # 1: scatters on both sides (glass always)
    mat_rgb2: wp.array(dtype=wp.vec3)  # specular transmittance (glass), the coat's reflectance (plastic)
    mat_eta: wp.array(dtype=wp.vec3)  # relative index of refraction (glass, plastic: [0]); conductors' eta per channel
    mat_k: wp.array(dtype=wp.vec3)  # conductors' k
    mat_param: wp.array(dtype=wp.vec4)  # alpha, distribution (kernels/bsdfs.py), plastic's coat pick weight, fdr_int
    mat_nonlinear: wp.array(dtype=wp.int32)  # plastic's nonlinear flag
    mat_table: wp.array(dtype=wp.int32)  # roughplastic: its first entry in rough_tables (64 per material)
    rough_tables: wp.array(dtype=float)  # roughplastic's coat transmittance tables (kernels/materials.py)
    mat_texture: wp.array(dtype=wp.int32)  # the texture that gives mat_rgb per point, -1 none (kernels/textures.py)
    tex_kind: wp.array(dtype=wp.int32)  # 0 checkerboard, 1 bitmap
    tex_uv_u: wp.array(dtype=wp.vec3)  # to_uv: u' = row_u . (u, v, 1)
    tex_uv_v: wp.array(dtype=wp.vec3)
    tex_color0: wp.array(dtype=wp.vec3)
    tex_color1: wp.array(dtype=wp.vec3)
    tex_start: wp.array(dtype=wp.int32)  # a bitmap's first texel in tex_texels (rows from the image's top)
    tex_size: wp.array(dtype=wp.vec2i)  # width, height
    tex_mode: wp.array(dtype=wp.vec2i)  # nearest (1) or bilinear (0); wrap: repeat 0, mirror 1, clamp 2
    tex_texels: wp.array(dtype=wp.vec3)
    light_center: wp.array(dtype=wp.vec3)
    light_half_u: wp.array(dtype=wp.vec3)
    light_half_v: wp.array(dtype=wp.vec3)
    light_normal: wp.array(dtype=wp.vec3)
    light_radiance: wp.array(dtype=wp.vec3)
    light_area: wp.array(dtype=float)
    num_lights: int
    light_quad: wp.array(dtype=wp.int32)  # the quad that is light l, -1 if it is triangles
    light_rect: wp.array(dtype=wp.int32)  # 1 if light l is a rectangle (solid-angle sampling applies), else 0
    # other area lights (kernels/lights.py); light_radiance holds the parallelograms' num_lights entries, then one per
    # sphere light, then one per mesh light: the index a hit's ``light`` names
    sphere_light: wp.array(dtype=wp.int32)  # per sphere: its light index, -1 if it does not emit
    sl_sphere: wp.array(dtype=wp.int32)  # sphere light j is sphere sl_sphere[j] (light index num_lights + j)
    num_sphere_lights: int
    ml_face: wp.array(dtype=wp.int32)  # the faces of every mesh light, light after light
    ml_cdf: wp.array(dtype=float)  # per face: its light's area CDF up to and including it (1 at each light's last)
    ml_start: wp.array(dtype=wp.int32)  # mesh light k's faces are ml_face[ml_start[k] : ml_start[k] + ml_count[k]]
    ml_count: wp.array(dtype=wp.int32)
    ml_area: wp.array(dtype=float)  # its total area (light index num_lights + num_sphere_lights + k)
    num_mesh_lights: int
    pl_position: wp.array(dtype=wp.vec3)  # point lights
    pl_intensity: wp.array(dtype=wp.vec3)
    num_point_lights: int
    spot_position: wp.array(dtype=wp.vec3)  # spot lights
    spot_to_local: wp.array(dtype=wp.mat33)  # world -> the light's frame (its axis is local +z)
    spot_intensity: wp.array(dtype=wp.vec3)
    spot_cone: wp.array(dtype=wp.vec4)  # cos(cutoff), cutoff, beam width (radians), cos(beam width)
    num_spot_lights: int
    dl_direction: wp.array(dtype=wp.vec3)  # directional lights: unit direction of travel
    dl_irradiance: wp.array(dtype=wp.vec3)
    num_directional_lights: int
    env_radiance: wp.vec3  # the constant environment's radiance (when the scene has one)
    env_image: wp.array(dtype=wp.vec3)  # Mitsuba's envmap (kernels/envmap.py): H x W texels, row by row
    env_width: int
    env_height: int
    env_to_local: wp.mat33  # world -> the map's frame (directions)
    env_to_world: wp.mat33
    env_scale: float
    env_row_cdf: wp.array(dtype=float)  # H - 1 rows of cells: marginal CDF
    env_col_cdf: wp.array(dtype=float)  # W per row: the CDF of the cells within the row


@wp.struct
class PassParams:
    """Sample passes pass_index .. pass_index + pass_count - 1 over a set of image rows (a tile: rows row_offset,
    row_offset + row_stride, ...)."""

    seed: wp.uint32
    pass_index: wp.uint32
    pass_count: int
    row_offset: int
    row_stride: int
    max_depth: int  # -1: unlimited
    rr_depth: int
    light_samples: int
    hide_emitters: int
    replicates: int  # R: pass p is a sample of replicate p mod R (its own Sobol' scramble)
    grad_material: int  # gradient variants: the material whose reflectance is differentiated (-1: none)
    grad_light: int  # ... the parallelogram light whose radiance is (-1: none)


@wp.struct
class Adjoint:
    """Path replay's inputs and outputs (backward gradient variants; elsewhere empty): each pixel's weight
    dLoss/dpixel / spp, and the float64 adjoints of the material reflectances and parallelogram radiances, one
    row of them per tile (a tile is rendered by one worker at a time: Warp's CPU atomics are plain adds)."""

    weight: wp.array(dtype=wp.vec3)
    rgb: wp.array(dtype=wp.vec3d)  # [tile * num_materials + material]
    radiance: wp.array(dtype=wp.vec3d)  # [tile * num_lights + light]
    num_materials: int
    num_lights: int


@wp.struct
class Ray:
    o: wp.vec3
    d: wp.vec3  # unit
    tmax: float


@wp.struct
class Hit:
    """Nearest intersection. Normals are unit and not flipped toward the ray."""

    t: float
    p: wp.vec3
    ng: wp.vec3  # geometric normal: triangle winding, or outward for spheres
    ns: wp.vec3  # shading normal
    scale: float  # magnitude of the coordinates p was computed from (for ray offsets)
    material: int
    light: int  # -1 if the surface does not emit
    sphere: int  # sphere index, -1 otherwise
    quad: int  # quad index, -1 otherwise
    face: int  # triangle index on meshes (set only there: sphere and quad both -1 mean a triangle)
    bary: wp.vec2  # on triangles: the weights of the face's corners 0 and 1 (for texture coordinates)
