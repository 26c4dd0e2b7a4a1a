"""Triangle meshes from OBJ and PLY files (read by trimesh; the common OBJ and binary PLY here, without importing
it), Mitsuba's ``serialized`` files (read here: zlib and a fixed binary layout), and Mitsuba's vertex-normal
recomputation.

``read_mesh`` returns the file's geometry in object space, one :class:`MeshPart` per trimesh
geometry (an OBJ with several materials or objects gives several), each with the file's vertex
normals or None where the file has none. Problems raise :class:`MeshFileError` with a one-line
message; the loader turns it into a SceneError naming the scene element.
"""

from __future__ import annotations

import io
import logging
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np


class MeshFileError(Exception):
    """A mesh file that cannot be used (missing, unreadable, not the format, no faces, bad numbers)."""


@dataclass
class MeshPart:
    vertices: np.ndarray  # (N, 3) float64
    faces: np.ndarray  # (M, 3) int64
    normals: np.ndarray | None  # (N, 3) float64 as stored in the file (not normalized), or None
    uv: np.ndarray | None = None  # (N, 2) float64 texture coordinates as stored in the file (not flipped), or None


def _one_line(e: BaseException) -> str:
    text = " ".join(str(e).split())
    return f"{type(e).__name__}: {text}" if text else type(e).__name__


def _parts_from_kwargs(kwargs_list) -> list[MeshPart]:
    parts = []
    for kw in kwargs_list:
        faces = kw.get("faces")
        if faces is None or len(faces) == 0:
            continue
        vertices = np.asarray(kw["vertices"], dtype=np.float64).reshape(-1, 3)
        faces = np.asarray(faces)
        if faces.ndim != 2 or faces.shape[1] not in (3, 4):
            raise MeshFileError(f"has faces that are not triangles or quads (shape {faces.shape})")
        if faces.shape[1] == 4:  # fan-split quads as Mitsuba's OBJ reader does: (0,1,2), (0,2,3)
            faces = np.concatenate([faces[:, [0, 1, 2]], faces[:, [0, 2, 3]]])
        faces = faces.astype(np.int64)
        normals = kw.get("vertex_normals")
        if normals is not None:
            normals = np.asarray(normals, dtype=np.float64).reshape(-1, 3)
            if normals.shape != vertices.shape:
                normals = None
        uv = getattr(kw.get("visual"), "uv", None)  # trimesh splits OBJ vertices by (v, vt, vn), as Mitsuba
        if uv is not None:
            uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
            if len(uv) != len(vertices):
                uv = None
        parts.append(MeshPart(vertices, faces, normals, uv))
    return parts


SERIALIZED_HEADER = 0x041C  # Mitsuba's MI_FILEFORMAT_HEADER
SERIALIZED_FLAGS = {"normals": 0x0001, "texcoords": 0x0002, "colors": 0x0008, "double": 0x2000}


def read_serialized(path: Path, shape_index: int = 0) -> MeshPart:
    """Mesh ``shape_index`` of a Mitsuba ``.serialized`` file (src/shapes/serialized.cpp, versions 3 and 4): a
    little-endian header (format 0x041C, version), a zlib stream per mesh (flags, a name in version 4, vertex and
    face counts, positions, optional normals, texcoords and colours, uint32 indices), and at the end of the file the
    meshes' offsets and their count."""
    import struct
    import zlib

    try:
        data = Path(path).read_bytes()
    except OSError as e:
        raise MeshFileError(f"cannot be read ({e.strerror or _one_line(e)})") from None
    try:
        fmt, version = struct.unpack_from("<hh", data, 0)
        if fmt != SERIALIZED_HEADER:
            raise MeshFileError("is not a Mitsuba serialized file (bad header)")
        if version not in (3, 4):
            raise MeshFileError(f"has serialized version {version} (supported: 3, 4)")
        start = 0
        if shape_index != 0:
            (count,) = struct.unpack_from("<I", data, len(data) - 4)
            if shape_index >= count:
                raise MeshFileError(f"has {count} meshes: shape_index {shape_index} is out of range")
            if version == 4:
                (start,) = struct.unpack_from("<Q", data, len(data) - 8 * (count - shape_index) - 4)
            else:
                (start,) = struct.unpack_from("<I", data, len(data) - 4 * (count - shape_index + 1))
        body = zlib.decompressobj().decompress(data[start + 4:])
        (flags,) = struct.unpack_from("<I", body, 0)
        pos = 4
        if version == 4:
            end = body.index(b"\0", pos)
            pos = end + 1
        nv, nf = struct.unpack_from("<QQ", body, pos)
        pos += 16
        real = np.float64 if flags & SERIALIZED_FLAGS["double"] else np.float32

        def take(n, dtype):
            nonlocal pos
            a = np.frombuffer(body, dtype=np.dtype(dtype).newbyteorder("<"), count=n, offset=pos)
            pos += a.nbytes
            return a

        vertices = take(3 * nv, real).reshape(-1, 3).astype(np.float64)
        normals = take(3 * nv, real).reshape(-1, 3).astype(np.float64) if flags & SERIALIZED_FLAGS["normals"] else None
        uv = take(2 * nv, real).reshape(-1, 2).astype(np.float64) if flags & SERIALIZED_FLAGS["texcoords"] else None
        if flags & SERIALIZED_FLAGS["colors"]:
            take(3 * nv, real)
        faces = take(3 * nf, np.uint32).reshape(-1, 3).astype(np.int64)
    except MeshFileError:
        raise
    except (struct.error, zlib.error, ValueError) as e:
        raise MeshFileError(f"is a truncated or corrupt serialized file ({_one_line(e)})") from None
    part = MeshPart(vertices=vertices, faces=faces, normals=normals, uv=uv)
    _check_parts([part])
    return part


def _check_parts(parts: list[MeshPart]) -> None:
    if not parts or not any(len(p.faces) for p in parts):
        raise MeshFileError("has no faces")
    for p in parts:
        if p.faces.min() < 0 or p.faces.max() >= len(p.vertices):
            raise MeshFileError("has a face that references a vertex that does not exist")
        if not np.all(np.isfinite(p.vertices)):
            raise MeshFileError("has a vertex position that is NaN or infinite")
        if p.normals is not None:
            lengths = np.linalg.norm(p.normals, axis=1)
            if not np.all(np.isfinite(lengths)) or np.any(lengths == 0):
                raise MeshFileError("has a vertex normal that is zero, NaN or infinite")
        if p.uv is not None and not np.all(np.isfinite(p.uv)):
            raise MeshFileError("has a texture coordinate that is NaN or infinite")


_OBJ_SIMPLE_KEYS = {b"v", b"vn", b"f", b"s"}
_OBJ_KEY = re.compile(rb"^([^\s#]\S*)", re.M)
_OBJ_INDENTED = re.compile(rb"^[ \t]+\S", re.M)
_N = rb"[ \t]+(\S+)"
_OBJ_V = re.compile(rb"^v" + _N * 3 + rb"(?:[ \t]+\S+[ \t]+\S+[ \t]+\S+)?[ \t]*\r?$", re.M)
_OBJ_VN = re.compile(rb"^vn" + _N * 3 + rb"[ \t]*\r?$", re.M)
_OBJ_F = re.compile(rb"^f" + _N * 3 + rb"[ \t]*\r?$", re.M)


def read_simple_obj(data: bytes) -> list[MeshPart] | None:
    """The common OBJ, parsed here: only ``v`` (3 numbers, or 6 with colours), ``vn``, ``s``, comment and triangle
    ``f`` lines, corners written ``a`` or ``a//a`` (normal index = vertex index, one normal per vertex), positive
    indices in range. Vertices no face uses are dropped (as trimesh does; with normals, trimesh reads the file).

    Importing trimesh costs about a second of every process (it imports scipy where installed), far more than the
    seed's meshes take to parse. None where the file uses anything else (objects, groups, materials, texture
    coordinates, polygons, negative indices, ...): trimesh reads those, so both paths give the same arrays
    (tests/test_loader.py compares them).
    """
    keys = _OBJ_KEY.findall(data)
    if not set(keys) <= _OBJ_SIMPLE_KEYS or _OBJ_INDENTED.search(data):
        return None  # trimesh skips some indented lines
    v, vn, f = _OBJ_V.findall(data), _OBJ_VN.findall(data), _OBJ_F.findall(data)
    if not v or not f or (len(v), len(vn), len(f)) != (keys.count(b"v"), keys.count(b"vn"), keys.count(b"f")):
        return None  # a line of another form (a 4-number v, a polygon, an empty f, a trailing comment)
    joined = b" ".join(b" ".join(tri) for tri in f)
    slashes = joined.count(b"/")
    if slashes not in (0, 6 * len(f)):  # every corner "a", or every corner "a//n"
        return None
    try:
        toks = joined.replace(b"//", b" ").split()
        if len(toks) != 3 * len(f) * (2 if slashes else 1):
            return None  # "a/b/c" split into more pieces, or "a//" into fewer
        idx = np.array(toks, dtype=np.int64).reshape(3 * len(f), -1)  # ValueError on "a/b" (negatives: below)
        vertices = np.array(v, dtype=np.float64)
        normals = np.array(vn, dtype=np.float64).reshape(-1, 3) if vn else None
    except ValueError:
        return None
    if idx.min() < 1 or idx.max() > len(vertices):
        return None
    faces = (idx[:, 0] - 1).reshape(-1, 3)
    used = np.zeros(len(vertices), dtype=bool)
    used[faces] = True
    if idx.shape[1] == 2:
        if normals is None or len(normals) != len(vertices) or np.any(idx[:, 0] != idx[:, 1]) or not used.all():
            return None
    elif normals is not None:
        return None
    elif not used.all():
        faces = (np.cumsum(used) - 1)[faces]
        vertices = vertices[used]
    return [MeshPart(vertices, faces, normals, None)]


_PLY_SCALARS = {b"float": "f4", b"float32": "f4", b"double": "f8", b"float64": "f8"}
_PLY_COUNTS = {b"uchar": "u1", b"uint8": "u1"}
_PLY_INDICES = {b"int": "i4", b"int32": "i4", b"uint": "u4", b"uint32": "u4"}
_PLY_FORMATS = {b"binary_little_endian": "<", b"binary_big_endian": ">"}
_PLY_VERTEX = ({b"x", b"y", b"z"}, {b"x", b"y", b"z", b"nx", b"ny", b"nz"})


def read_simple_ply(data: bytes) -> list[MeshPart] | None:
    """The common binary PLY, read here with numpy: one ``vertex`` element of float or double ``x y z`` and
    optionally ``nx ny nz``, then one ``face`` element whose only property is a ``uchar`` count and ``int`` or
    ``uint`` ``vertex_indices`` (or ``vertex_index``), every face a triangle or every face a quad. None for anything
    else (ASCII, colours, texture coordinates, other elements, mixed polygons, ...): trimesh reads those, and both
    paths give the same arrays (tests/test_loader.py compares them). Importing trimesh costs about a second."""
    end = data.find(b"end_header")
    if not data.startswith(b"ply") or end < 0:
        return None
    body = end + len(b"end_header")
    if data[body:body + 2] == b"\r\n":
        body += 2
    elif data[body:body + 1] == b"\n":
        body += 1
    else:
        return None
    lines = [ln.split() for ln in data[:end].splitlines()[1:]]
    lines = [ln for ln in lines if ln and ln[0] not in (b"comment", b"obj_info")]
    if not lines or len(lines[0]) != 3 or lines[0][0] != b"format" or lines[0][2] != b"1.0":
        return None
    order = _PLY_FORMATS.get(lines[0][1])
    if order is None:
        return None
    elements = []
    for ln in lines[1:]:
        if ln[0] == b"element" and len(ln) == 3 and ln[2].isdigit():
            elements.append((ln[1], int(ln[2]), []))
        elif ln[0] == b"property" and elements:
            elements[-1][2].append(ln[1:])
        else:
            return None
    if [e[0] for e in elements] != [b"vertex", b"face"]:
        return None
    (_, nv, vprops), (_, nf, fprops) = elements
    if any(len(p) != 2 or p[0] not in _PLY_SCALARS for p in vprops):
        return None
    names = [p[1] for p in vprops]
    if len(set(names)) != len(names) or set(names) not in _PLY_VERTEX:
        return None
    if (len(fprops) != 1 or len(fprops[0]) != 4 or fprops[0][0] != b"list" or fprops[0][1] not in _PLY_COUNTS
            or fprops[0][2] not in _PLY_INDICES or fprops[0][3] not in (b"vertex_indices", b"vertex_index")):
        return None
    vdtype = np.dtype([(n.decode(), order + _PLY_SCALARS[t]) for t, n in vprops])
    vbytes = nv * vdtype.itemsize
    if nv == 0 or nf == 0 or len(data) < body + vbytes + 1:
        return None
    first = data[body + vbytes]  # every face's count must be this one (3 or 4)
    if first not in (3, 4):
        return None
    fdtype = np.dtype([("n", "u1"), ("i", order + _PLY_INDICES[fprops[0][2]], (first,))])
    if len(data) != body + vbytes + nf * fdtype.itemsize:
        return None  # mixed polygon sizes, or trailing bytes
    vert = np.frombuffer(data, vdtype, nv, body)
    face = np.frombuffer(data, fdtype, nf, body + vbytes)
    if np.any(face["n"] != first):
        return None
    kw = {"vertices": np.column_stack([vert[a] for a in "xyz"]), "faces": face["i"]}
    if "nx" in vdtype.names:
        kw["vertex_normals"] = np.column_stack([vert[a] for a in ("nx", "ny", "nz")])
    return _parts_from_kwargs([kw])


def read_mesh(path: Path, kind: str) -> list[MeshPart]:
    """Read an ``obj`` or ``ply`` file: the common OBJ and binary PLY here (:func:`read_simple_obj`,
    :func:`read_simple_ply`), everything else with trimesh (no merging or reordering of vertices)."""
    try:
        data = Path(path).read_bytes()
    except OSError as e:
        raise MeshFileError(f"cannot be read ({e.strerror or _one_line(e)})") from None
    if not data.strip():
        raise MeshFileError("is empty")
    if kind == "obj" and b"\0" in data:
        raise MeshFileError("is binary data, not a text OBJ file")
    parts = read_simple_obj(data) if kind == "obj" else read_simple_ply(data) if kind == "ply" else None
    if parts is None:
        parts = read_with_trimesh(data, kind)
    _check_parts(parts)
    return parts


def read_with_trimesh(data: bytes, kind: str) -> list[MeshPart]:
    """The parts of an ``obj`` or ``ply`` file's bytes as trimesh reads them (not yet checked)."""
    from trimesh.exchange import obj as tobj
    from trimesh.exchange import ply as tply

    # trimesh logs (and then skips) things like a missing .mtl; that is not our user's concern.
    log = logging.getLogger("trimesh")
    level = log.level
    log.setLevel(logging.CRITICAL)
    try:
        if kind == "obj":
            loaded = tobj.load_obj(io.BytesIO(data))
            if "geometry" in loaded:
                kwargs_list = list(loaded["geometry"].values())
            else:
                kwargs_list = [loaded] if "vertices" in loaded else []
        elif kind == "ply":
            kwargs_list = [tply.load_ply(io.BytesIO(data))]
        else:  # pragma: no cover - the loader only asks for obj and ply
            raise ValueError(kind)
        return _parts_from_kwargs(kwargs_list)
    except MeshFileError:
        raise
    except Exception as e:  # trimesh raises many kinds on malformed files
        raise MeshFileError(f"could not be read as {kind.upper()} ({_one_line(e)})") from None
    finally:
        log.setLevel(level)


def join_arrays(arrays: list[np.ndarray]) -> np.ndarray:
    """np.concatenate, without the copy for one array: a 5M-triangle mesh's faces are 126 MB, and fresh memory
    costs 2.7 s a GiB on a VM whose host backs it lazily."""
    return arrays[0] if len(arrays) == 1 else np.concatenate(arrays)


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Smooth vertex normals as Mitsuba's ``Mesh::recompute_vertex_normals``.

    Each face adds its unit normal weighted by its corner angle at each of its vertices
    (Thuermer and Wuethrich 1998); zero-area faces add nothing (``kernels/mesh_normals.py``, on the CPU). A vertex
    whose sum is zero (unused, or only on degenerate faces) gets (1, 0, 0), Mitsuba's placeholder.
    """
    import warp as wp

    from kernels.mesh_normals import accumulate_vertex_normals
    from pathtracer.warp_setup import init_warp

    init_warp()
    out = wp.zeros(len(vertices), dtype=wp.vec3d, device="cpu")
    if len(faces):
        wp.launch(accumulate_vertex_normals, dim=len(faces), device="cpu",
                  inputs=[wp.array(np.ascontiguousarray(vertices, dtype=np.float64), dtype=wp.vec3d, device="cpu"),
                          wp.array(np.ascontiguousarray(faces, dtype=np.int32).reshape(-1), dtype=wp.int32,
                                   device="cpu")],
                  outputs=[out])
    out = out.numpy()
    length = np.sqrt(np.einsum("ij,ij->i", out, out))
    bad = ~(length > 0)
    out[bad] = (1.0, 0.0, 0.0)
    length[bad] = 1.0
    out /= length[:, None]
    return out
