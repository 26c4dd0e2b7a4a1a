"""Mitsuba 3 XML -> the Mitsuba-shaped dict that ``pathtracer.loader`` turns into a Scene.

Only the syntax lives here: expat builds a tiny element tree with line numbers, ``$name``
parameters are substituted as Mitsuba's parser does, property tags become Python values,
``<transform>`` blocks become 4x4 numpy matrices (each operation left-multiplies, in document
order) and ``<ref>`` becomes ``{'type': 'ref', 'id': ...}``. Plugin semantics (which properties a
plugin has, defaults, ranges) are checked once, on the dict, for XML and dict scenes alike.

Every dict built here is an :class:`XmlDict` that remembers where its element and each of its
properties came from, so the dict layer can name ``line 12 <shape type="sphere">`` in errors (and
``inc/walls.xml line 3 <shape type="obj">`` for an element from an included file).

Files and folders follow Mitsuba 3.9's ``FileResolver`` (src/core/fresolver.cpp, parser.cpp):

* ``<include filename>`` is looked up in the folder of the file holding the tag first, then in the
  parse-time resolver. An included ``<scene>`` has its children merged in place, in document
  order, into the element holding the ``<include>``; any other root (``<bsdf>``, ``<shape>``, ...)
  becomes one child object. Every file needs its own ``version``; ``<default>``s and parameters are
  shared by all files (the first definition wins, passed parameters beat defaults).
* ``<path value>`` (a direct child of a file's root) adds a folder, searched before the folders
  added earlier. In the top-level file it applies to everything resolved later (mesh files too:
  :attr:`XmlDict.search_paths`, :func:`resolve_file`); in an included file only to what that file
  resolves while it is parsed (its includes and spectrum files), as in Mitsuba.
* The parse-time resolver starts as [scene folder, working directory]; an ``<include>`` parses its
  file with the includer's folder in front, so a ``<spectrum filename>`` in an included file is
  found relative to the *includer's* folder (Mitsuba's behaviour).

Scenes older than version 2.0.0 get Mitsuba's ``upgrade_from_v1`` and nothing else: property names
go from camelCase to snake_case, diffuse ``diffuse_reflectance`` becomes ``reflectance``, and the
0.x texture offsets/scales are refused (give the texture a to_uv instead). Versions 2.x and 3.x are read
as they are.
"""

from __future__ import annotations

import os
import re
import xml.parsers.expat
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import transform as tf
from .errors import SceneError

# Element tags that make plugin objects, and the category each one makes.
OBJECT_TAGS = {"integrator", "sensor", "film", "sampler", "rfilter", "bsdf", "shape", "emitter", "texture"}
# Mitsuba tags this renderer does not support at all, with a hint.
UNSUPPORTED_TAGS = {
    "medium": "participating media are not supported",
    "phase": "phase functions are not supported",
    "volume": "volumes are not supported",
    "field": "<field> is not supported",
    "alias": "<alias> is not supported",
}
PROPERTY_TAGS = {"float", "integer", "boolean", "string", "rgb", "point", "vector", "spectrum"}
TRANSFORM_OPS = {"translate", "rotate", "scale", "matrix", "lookat"}
ALL_TAGS = sorted(OBJECT_TAGS | PROPERTY_TAGS | {"scene", "ref", "transform", "default", "include", "path"})
# Mitsuba's ParserConfig::max_include_depth: the top-level file is depth 0, so at most 15 files deep.
MAX_INCLUDE_DEPTH = 15
# Mitsuba 0.x texture coordinate offsets/scales (upgrade_from_v1 turns them into "to_uv").
_V1_UV_PROPS = ("uoffset", "voffset", "uscale", "vscale")

_FLOAT_RE = re.compile(r"[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?")
_NONFINITE_RE = re.compile(r"[+-]?(nan|inf|infinity)", re.IGNORECASE)
_INT_RE = re.compile(r"[+-]?\d+")
_SPLIT_RE = re.compile(r"[\s,]+")
_VERSION_RE = re.compile(r"(\d+)\.(\d+)\.(\d+)")


class Point3(tuple):
    """A 3-vector written as <point> or <vector> (kept apart from colours, as Mitsuba does)."""


class XmlDict(dict):
    """A plugin dict built from an XML element; remembers where it and its properties were written.

    The root (the ``<scene>``) also carries ``search_paths``: see :func:`resolve_file`.
    """

    where: str
    category: str
    prop_where: dict
    search_paths: list | None = None  # set on the root returned by parse_file

    def __init__(self, where: str, category: str):
        super().__init__()
        self.where = where
        self.category = category
        self.prop_where = {}


def resolve_file(filename: str, search_paths) -> Path:
    """Find a file the way Mitsuba's ``FileResolver.resolve`` does, for mesh and texture filenames.

    Contract: ``search_paths`` is a root :class:`XmlDict`'s ``search_paths`` (folders, most
    preferred first: the top-level file's ``<path>`` folders, last declared first, then the scene
    file's folder, then the working directory at parse time) or any such sequence of paths. An
    absolute ``filename`` is returned as it is. A relative one is joined to each folder in order
    and the first candidate that exists is returned; if none exists, the first candidate is
    returned (or ``Path(filename)`` when ``search_paths`` is empty), so the caller's "cannot read"
    error names a real place. Nothing is opened or checked beyond ``exists()``.

    Mitsuba resolves mesh and texture filenames after parsing, with the top-level resolver only,
    so a mesh named in an included file is found relative to the top-level scene's folder (and its
    ``<path>``s), not relative to the included file.
    """
    p = Path(filename)
    if p.is_absolute():
        return p
    candidates = [Path(base) / p for base in search_paths]
    for c in candidates:
        if c.exists():
            return c
    return candidates[0] if candidates else p


@dataclass(eq=False)
class _File:
    """One XML file of the scene: where it is, how errors name it, and its root's version."""

    path: Path
    label: str  # "" for the top-level file; else its path relative to the top-level scene's folder
    version: tuple = ()
    root: _Element | None = None

    @property
    def folder(self) -> Path:
        return self.path.parent


@dataclass(eq=False)
class _Element:
    tag: str
    attrs: dict
    line: int
    children: list = field(default_factory=list)
    file: _File | None = None

    def describe(self) -> str:
        shown = " ".join(f'{k}="{self.attrs[k]}"' for k in ("type", "name", "id", "filename") if k in self.attrs)
        prefix = f"{self.file.label} " if self.file is not None and self.file.label else ""
        return f"{prefix}line {self.line} <{self.tag}{' ' + shown if shown else ''}>"


class _Param:
    __slots__ = ("key", "value", "used")

    def __init__(self, name: str, value: str, used: bool):
        self.key, self.value, self.used = "$" + name, value, used


def _param_string(name: str, value) -> str:
    if isinstance(value, (bool, np.bool_)):
        return "true" if value else "false"
    if isinstance(value, (int, float, str, np.integer, np.floating)):
        return str(value)
    raise TypeError(f"parameter {name!r}: give a number, string or bool, not {type(value).__name__}")


def _camel_to_snake(name: str) -> str:
    """Mitsuba's ``camel_to_underscore_case`` (parser.cpp), ASCII only as there.

    An uppercase letter right after a lowercase one starts a new lowercase word, and the uppercase
    letters that follow it are lowered with it: toWorld -> to_world, intIOR -> int_ior.
    """
    out, i = [], 0
    while i < len(name):
        c = name[i]
        if i > 0 and "a" <= name[i - 1] <= "z" and "A" <= c <= "Z":
            out.append("_" + c.lower())
            while i + 1 < len(name) and "A" <= name[i + 1] <= "Z":
                i += 1
                out.append(name[i].lower())
        else:
            out.append(c)
        i += 1
    return "".join(out)


def _parse_tree(data: bytes, source: str, file: _File, context: str = "") -> _Element:
    """expat -> _Element tree. Errors name ``file`` (by its label when it is an included file);
    ``context`` (e.g. "included by line 3 <include ...>") is appended to them."""
    label = f"{file.label} " if file.label else ""
    extra = f" ({context})" if context else ""

    def fail(line: int | None, problem: str):
        where = f"{label}line {line}" if line is not None else label.strip()
        raise SceneError(source, where, problem + extra)

    if not data.strip():
        fail(None, "the file is empty (expected a Mitsuba XML <scene>)")
    if b"\0" in data:
        fail(None, "the file is binary data, not a Mitsuba XML scene")

    parser = xml.parsers.expat.ParserCreate()
    stack: list[_Element] = []
    roots: list[_Element] = []

    def start(tag, attrs):
        el = _Element(tag, dict(attrs), parser.CurrentLineNumber, file=file)
        (stack[-1].children if stack else roots).append(el)
        stack.append(el)

    def end(tag):
        stack.pop()

    def doctype(*args):
        fail(parser.CurrentLineNumber, "<!DOCTYPE> declarations are not supported")

    parser.StartElementHandler = start
    parser.EndElementHandler = end
    parser.StartDoctypeDeclHandler = doctype
    try:
        parser.Parse(data, True)
    except xml.parsers.expat.ExpatError as e:
        msg = xml.parsers.expat.errors.messages.get(e.code, str(e))
        line, problem = e.lineno, f"malformed XML: {msg} (column {e.offset + 1})"
    else:
        file.root = roots[0]
        return roots[0]
    fail(line, problem)


class _Converter:
    """Walks the element tree in document order, as Mitsuba's parser does."""

    def __init__(self, source: str, params: dict, top: _File):
        self.source = source
        self.top = top
        # Mitsuba's global FileResolver while parsing: load_file puts the scene's folder in front of
        # the working directory; <path> and <include> change it as they are met (see the module doc).
        self.resolver: list[Path] = [top.folder, Path.cwd()]
        self.include_chain: list[_File] = [top]
        self.params: list[_Param] = []
        for name, value in params.items():
            try:
                self.params.append(_Param(name, _param_string(name, value), used=False))
            except TypeError as e:
                raise SceneError(source, "", str(e)) from None
        self._sort_params()

    def _sort_params(self):
        self.params.sort(key=lambda p: -len(p.key))

    def fail(self, el: _Element, problem: str):
        raise SceneError(self.source, " ".join(el.describe().split()), " ".join(problem.split()))

    # -- attributes -------------------------------------------------------------------------

    def substitute(self, el: _Element):
        """Replace ``$name`` in every attribute (longest names first; ``\\$`` escapes a dollar)."""
        for k, value in el.attrs.items():
            if "$" not in value:
                continue
            for p in self.params:
                pos = 0
                while (pos := value.find(p.key, pos)) != -1:
                    if pos > 0 and value[pos - 1] == "\\":
                        pos += len(p.key)
                    else:
                        value = value[:pos] + p.value + value[pos + len(p.key):]
                        p.used = True
                        pos += len(p.value)
            for m in re.finditer(r"\$", value):
                if m.start() == 0 or value[m.start() - 1] != "\\":
                    name = re.match(r"[A-Za-z0-9_]*", value[m.start() + 1:]).group(0)
                    self.fail(el, f'undefined parameter "${name}" in attribute {k}="{el.attrs[k]}" '
                                  f"(define it with <default name=\"{name}\" value=\"...\"/> or pass it)")
            el.attrs[k] = value.replace("\\$", "$")

    def check_attrs(self, el: _Element, required: tuple = (), optional: tuple = ()):
        allowed = set(required) | set(optional)
        for k in el.attrs:
            if k not in allowed:
                self.fail(el, f'unexpected attribute "{k}" (allowed: {", ".join(sorted(allowed)) or "none"})')
        for k in required:
            if k not in el.attrs:
                self.fail(el, f'missing required attribute "{k}"')

    # -- values -----------------------------------------------------------------------------

    def number(self, el: _Element, text: str, what: str = "value") -> float:
        s = text.strip()
        if _NONFINITE_RE.fullmatch(s):
            self.fail(el, f'{what} "{text}" is not a finite number')
        if not _FLOAT_RE.fullmatch(s):
            self.fail(el, f'{what} "{text}" is not a number')
        v = float(s)
        if not np.isfinite(v):
            self.fail(el, f'{what} "{text}" is not a finite number')
        return v

    def numbers(self, el: _Element, text: str, counts: tuple, what: str = "value") -> list[float]:
        tokens = [t for t in _SPLIT_RE.split(text.strip()) if t]
        if len(tokens) not in counts:
            want = " or ".join(str(c) for c in counts)
            self.fail(el, f'{what} "{text}" must have {want} numbers (got {len(tokens)})')
        return [self.number(el, t, what) for t in tokens]

    def xyz(self, el: _Element, default: float) -> np.ndarray:
        """x/y/z attributes (missing ones take ``default``) or ``value`` (1 or 3 numbers)."""
        if "value" in el.attrs:
            if any(k in el.attrs for k in "xyz"):
                self.fail(el, 'cannot mix "value" with "x"/"y"/"z"')
            v = self.numbers(el, el.attrs["value"], (1, 3))
            return np.array(v * 3 if len(v) == 1 else v)
        return np.array([self.number(el, el.attrs[k], k) if k in el.attrs else default for k in "xyz"])

    def property_value(self, el: _Element):
        tag, a = el.tag, el.attrs
        if tag == "spectrum":
            return self.spectrum(el)
        if tag in ("point", "vector"):
            self.check_attrs(el, ("name",), ("value", "x", "y", "z"))
            if "value" not in a:
                for k in "xyz":
                    if k not in a:
                        self.fail(el, f'missing required attribute "{k}" (or give value="x y z")')
            return Point3(float(x) for x in self.xyz(el, 0.0))
        self.check_attrs(el, ("name", "value"))
        text = a["value"]
        if tag == "float":
            return self.number(el, text)
        if tag == "integer":
            if not _INT_RE.fullmatch(text.strip()) or len(text.strip()) > 40:
                self.fail(el, f'value "{text}" is not an integer (or is far out of range)')
            return int(text.strip())
        if tag == "boolean":
            low = text.strip().lower()
            if low not in ("true", "false"):
                self.fail(el, f'value "{text}" is not a boolean (true or false)')
            return low == "true"
        if tag == "string":
            return text
        if tag == "rgb":
            v = self.numbers(el, text, (1, 3))
            return {"type": "rgb", "value": v * 3 if len(v) == 1 else v}
        raise AssertionError(tag)

    def transform(self, el: _Element) -> np.ndarray:
        self.check_attrs(el, ("name",))
        m = np.eye(4)
        for op in el.children:
            self.substitute(op)
            a = op.attrs
            if op.tag == "translate":
                self.check_attrs(op, (), ("value", "x", "y", "z"))
                m = tf.translate(self.xyz(op, 0.0)) @ m
            elif op.tag == "scale":
                self.check_attrs(op, (), ("value", "x", "y", "z"))
                m = tf.scale(self.xyz(op, 1.0)) @ m
            elif op.tag == "rotate":
                self.check_attrs(op, ("angle",), ("value", "x", "y", "z"))
                axis = self.xyz(op, 0.0)
                angle = self.number(op, a["angle"], "angle")
                if not np.any(axis):
                    self.fail(op, "rotation axis cannot be zero")
                try:
                    m = tf.rotate(axis, angle) @ m
                except ValueError as e:
                    self.fail(op, f"{e}: Mitsuba does not normalize it, so it would not be a rotation there")
            elif op.tag == "matrix":
                self.check_attrs(op, ("value",))
                v = self.numbers(op, a["value"], (16, 9))
                mat = np.eye(4)
                if len(v) == 16:
                    mat = np.array(v).reshape(4, 4)
                else:
                    mat[:3, :3] = np.array(v).reshape(3, 3)
                m = mat @ m
            elif op.tag == "lookat":
                self.check_attrs(op, ("origin", "target"), ("up",))
                origin = self.numbers(op, a["origin"], (3,), "origin")
                target = self.numbers(op, a["target"], (3,), "target")
                up = self.numbers(op, a["up"], (3,), "up") if a.get("up", "").strip() else None
                try:
                    m = tf.look_at(origin, target, up) @ m
                except ValueError as e:
                    self.fail(op, f"invalid lookat: {e}")
            else:
                self.fail(op, f"<{op.tag}> cannot appear inside <transform> "
                              f"(supported: {', '.join(sorted(TRANSFORM_OPS))})")
            if op.children:
                self.fail(op.children[0], f"<{op.children[0].tag}> cannot appear inside <{op.tag}>")
        if not np.all(np.isfinite(m)):
            self.fail(el, "the transform has NaN or infinite entries")
        return m

    def spectrum(self, el: _Element) -> dict:
        """``<spectrum>`` as Mitsuba's RGB variants read it: a uniform value or wavelength:value pairs.

        Gives ``{"type": "spectrum", "value": v}`` or ``{"type": "spectrum", "wavelengths": [...],
        "values": [...]}`` (floats, >= 2 pairs, wavelengths strictly increasing, all finite);
        :func:`pathtracer.spectra.spectrum_to_rgb` turns either into the colour Mitsuba uses.
        """
        a = el.attrs
        if "type" in a:
            self.fail(el, f'spectrum plugins (<spectrum type="{a["type"]}">) are not supported: give '
                          f'value="v", value="wavelength:value, ..." or filename="file.spd", or an <rgb>')
        self.check_attrs(el, ("name",), ("value", "filename"))
        has_value, has_file = bool(a.get("value", "").strip()), bool(a.get("filename", "").strip())
        if has_value == has_file:
            self.fail(el, '<spectrum> needs either a non-empty "value" or a "filename" (not both)')
        if has_file:
            return self.spectrum_file(el, a["filename"].strip())
        text = a["value"]
        tokens = [t for t in _SPLIT_RE.split(text.strip()) if t]
        if len(tokens) == 1 and ":" not in tokens[0]:
            return {"type": "spectrum", "value": self.number(el, tokens[0])}
        wavelengths, values = [], []
        for t in tokens:
            pair = t.split(":")
            if len(pair) != 2:
                self.fail(el, f'"{t}" in value="{text}" is not a wavelength:value pair '
                              f'(write value="400:0.1, 500:0.5, ..." or a single value)')
            wavelengths.append(self.number(el, pair[0], "wavelength"))
            values.append(self.number(el, pair[1], "value"))
        return self.spectrum_pairs(el, wavelengths, values, f'value="{text}"')

    def spectrum_file(self, el: _Element, filename: str) -> dict:
        """A text file of "wavelength value" lines; empty lines and ``#`` comments are skipped.

        Mitsuba resolves the name with the parse-time resolver (so, in an included file, relative
        to the includer's folder) and does not look at the extension.
        """
        path = resolve_file(filename, self.resolver)
        if not path.is_file():
            self.fail(el, f'spectrum file "{filename}" not found (looked in: {self.looked_in(filename)})')
        try:
            data = path.read_bytes()
        except OSError as e:
            self.fail(el, f'cannot read spectrum file "{path}" ({e.strerror or type(e).__name__})')
        try:
            text = data.decode("utf-8")
        except UnicodeDecodeError:
            text = None
        if text is None or "\0" in text:
            self.fail(el, f'spectrum file "{path}" is not a text file of "wavelength value" lines')
        wavelengths, values = [], []
        for n, line in enumerate(text.splitlines(), 1):
            body = line.split("#", 1)[0].strip()
            if not body:
                continue
            parts = body.split()
            if len(parts) != 2 or not all(_FLOAT_RE.fullmatch(x) for x in parts) or \
                    not all(np.isfinite(float(x)) for x in parts):
                shown = " ".join(line.split())
                self.fail(el, f'spectrum file "{path}" line {n}: expected "wavelength value" (two finite '
                              f'numbers), got "{shown[:60]}"')
            wavelengths.append(float(parts[0]))
            values.append(float(parts[1]))
        return self.spectrum_pairs(el, wavelengths, values, f'spectrum file "{path}"')

    def spectrum_pairs(self, el: _Element, wavelengths: list, values: list, what: str) -> dict:
        if len(wavelengths) < 2:
            self.fail(el, f"{what}: a spectrum needs at least 2 wavelength:value pairs (got {len(wavelengths)})")
        for w0, w1 in zip(wavelengths, wavelengths[1:]):
            if not w1 > w0:
                self.fail(el, f"{what}: wavelengths must increase strictly ({w1:g} follows {w0:g})")
        return {"type": "spectrum", "wavelengths": wavelengths, "values": values}

    def looked_in(self, filename: str, folders=None) -> str:
        """The candidates a relative name was tried at (for "not found" errors)."""
        if Path(filename).is_absolute():
            return filename
        candidates = (str(Path(b) / filename) for b in (self.resolver if folders is None else folders))
        return ", ".join(dict.fromkeys(candidates))

    # -- elements ---------------------------------------------------------------------------

    def object(self, el: _Element, category: str, depth: int = 0) -> XmlDict:
        """A plugin element and, in document order, everything nested in it."""
        if depth > 64:
            self.fail(el, "elements are nested too deeply")
        node = XmlDict(el.describe(), category)
        node["type"] = el.attrs.get("type", "scene")
        if "id" in el.attrs:
            node["id"] = el.attrs["id"]
        node.prop_where["type"] = node.prop_where["id"] = node.where
        self.children(node, el, el.children, depth, [0], at_file_root=el is el.file.root, merged=False)
        if el.file.version < (2, 0, 0):
            self.upgrade_from_v1(node, el)
        return node

    def children(self, node: XmlDict, el: _Element, children: list, depth: int, arg_counter: list,
                 at_file_root: bool, merged: bool):
        """Add ``children`` to ``node`` (built from ``el``). ``merged``: they are the children of an
        included ``<scene>``, merged into ``el`` (``at_file_root`` is then true: they are at the root
        of their own file, where ``<path>`` may appear)."""
        category = node.category
        for child in children:
            self.substitute(child)
            tag = child.tag
            if tag == "default":
                self.default(child)
                continue
            if tag == "path":
                self.path(child, at_file_root)
                continue
            if tag == "include":
                self.include(node, el, child, depth, arg_counter)
                continue
            if merged and (tag in PROPERTY_TAGS or tag in ("ref", "transform")):
                self.fail(child, f"<{tag}> at the root of an included <scene> is dropped by Mitsuba (only "
                                 f"objects are merged into {el.describe()}): move it into the element it "
                                 f"belongs to")
            if tag in OBJECT_TAGS:
                self.check_attrs(child, ("type",), ("id", "name"))
                value = self.object(child, tag, depth + 1)
            elif tag == "ref":
                self.check_attrs(child, ("id",), ("name",))
                value = XmlDict(child.describe(), "ref")
                value.update(type="ref", id=child.attrs["id"])
            elif tag in PROPERTY_TAGS:
                value = self.property_value(child)
                if child.children:
                    self.fail(child.children[0], f"<{child.children[0].tag}> cannot appear inside a property")
            elif tag == "transform":
                value = self.transform(child)
            else:
                self.unknown_tag(child)
            name = child.attrs.get("name")
            if tag in OBJECT_TAGS or tag == "ref":
                if not name:
                    name = child.attrs.get("id") if category == "scene" and tag != "ref" else None
                if not name:
                    name = f"_arg_{arg_counter[0]}"
                    arg_counter[0] += 1
            self.put(node, el, child, self.v1_name(el, name, child), value)

    def v1_name(self, el: _Element, name: str, child: _Element) -> str:
        """The property name ``node`` (built from ``el``) stores: Mitsuba's upgrade_from_v1 renames
        the properties of a node from a file older than 2.0.0 (only names written with ``name=``;
        the generated and id-derived ones have no capitals to change)."""
        if el.file.version < (2, 0, 0) and child.attrs.get("name"):
            return _camel_to_snake(name)
        return name

    def put(self, node: XmlDict, el: _Element, child: _Element, name: str, value):
        if name in ("type", "id"):
            self.fail(child, f'"{name}" is reserved and cannot be a property name')
        if name in node:
            renamed = child.attrs.get("name")
            how = f' (written "{renamed}", renamed for a version < 2.0.0 scene)' if renamed and renamed != name else ""
            self.fail(child, f'"{name}"{how} is given twice in {el.describe()} (first at {node.prop_where[name]})')
        node[name] = value
        node.prop_where[name] = child.describe()

    def upgrade_from_v1(self, node: XmlDict, el: _Element):
        """The rest of Mitsuba's upgrade_from_v1 for a node from a file older than 2.0.0."""
        if node["type"] == "diffuse" and "diffuse_reflectance" in node:
            if "reflectance" in node:
                self.fail(el, f'"diffuse_reflectance" (renamed "reflectance" for a version < 2.0.0 scene) and '
                              f'"reflectance" are both given (at {node.prop_where["diffuse_reflectance"]} and '
                              f'{node.prop_where["reflectance"]})')
            node["reflectance"] = node.pop("diffuse_reflectance")
            node.prop_where["reflectance"] = node.prop_where.pop("diffuse_reflectance")
        for key in _V1_UV_PROPS:
            if key in node:
                where = node.prop_where[key]
                raise SceneError(self.source, " ".join(where.split()),
                                 f'"{key}" (a Mitsuba 0.x texture coordinate offset/scale, which Mitsuba 3 '
                                 f'turns into "to_uv"): texture coordinate transforms are not supported in '
                                 f'this 0.x form (give the texture a to_uv)')

    def path(self, el: _Element, at_file_root: bool):
        """``<path value="folder">``: searched before the scene's folder (last declared first)."""
        self.check_attrs(el, ("value",))
        if el.children:
            self.fail(el.children[0], f"<{el.children[0].tag}> cannot appear inside <path>")
        if not at_file_root:
            self.fail(el, "<path> can only be a direct child of the root <scene>")
        value = el.attrs["value"].strip()
        if not value:
            self.fail(el, "the folder name is empty")
        folder = Path(value)
        tried = [str(folder)]
        if not folder.is_absolute():
            # Mitsuba: relative to this XML file's folder first, then through the resolver
            folder = el.file.folder / value
            tried = [str(folder)] + [str(Path(b) / value) for b in self.resolver]
            if not folder.exists():
                folder = resolve_file(value, self.resolver)
        if not folder.is_dir():
            self.fail(el, f'folder "{value}" not found (looked in: {", ".join(dict.fromkeys(tried))})')
        self.resolver.insert(0, folder)

    def include(self, node: XmlDict, el: _Element, inc: _Element, depth: int, arg_counter: list):
        """``<include filename="..." [name="..."]/>``, merged as Mitsuba 3.9's parser does."""
        self.check_attrs(inc, ("filename",), ("name",))
        if inc.children:
            self.fail(inc.children[0], f"<{inc.children[0].tag}> cannot appear inside <include>")
        filename = inc.attrs["filename"].strip()
        if not filename:
            self.fail(inc, "the filename is empty")
        if len(self.include_chain) >= MAX_INCLUDE_DEPTH:
            self.fail(inc, f"includes are nested more than {MAX_INCLUDE_DEPTH - 1} deep (Mitsuba's limit)")
        # Mitsuba: the folder of the file holding the tag goes in front of the resolver for the
        # lookup and while the included file is parsed; the resolver is restored afterwards.
        resolver = [inc.file.folder] + self.resolver
        path = resolve_file(filename, resolver)
        if not path.is_file():
            self.fail(inc, f'included file "{filename}" not found (looked in: {self.looked_in(filename, resolver)})')
        real = os.path.realpath(path)
        chain = [f.label or f.path.name for f in self.include_chain]
        if any(os.path.realpath(f.path) == real for f in self.include_chain):
            self.fail(inc, f"include cycle: {' -> '.join(chain + [self.label(path)])}")
        try:
            data = path.read_bytes()
        except OSError as e:
            self.fail(inc, f'cannot read included file "{path}" ({e.strerror or type(e).__name__})')
        file = _File(path, self.label(path))
        root = _parse_tree(data, self.source, file, f"included by {' '.join(inc.describe().split())}")
        saved = self.resolver
        self.resolver = resolver
        self.include_chain.append(file)
        try:
            self.substitute(root)
            if root.tag == "scene":
                self.check_attrs(root, ("version",))
                self.version(root)
                self.children(node, el, root.children, depth, arg_counter, at_file_root=True, merged=True)
                return
            if root.tag not in OBJECT_TAGS:
                what = "a property" if root.tag in PROPERTY_TAGS else f"<{root.tag}>"
                self.fail(root, f"the root of an included file must be <scene> or an object "
                                f"({', '.join(sorted(OBJECT_TAGS))}), not {what}")
            self.check_attrs(root, ("type", "version"), ("id",))
            self.version(root)
            value = self.object(root, root.tag, depth + 1)
        finally:
            self.resolver = saved
            self.include_chain.pop()
        name = inc.attrs.get("name")
        if not name:
            name = root.attrs.get("id") if node.category == "scene" else None
        if not name:
            name = f"_arg_{arg_counter[0]}"
            arg_counter[0] += 1
        self.put(node, el, inc, self.v1_name(el, name, inc), value)

    def label(self, path: Path) -> str:
        """How errors name an included file: relative to the top-level scene's folder."""
        try:
            return os.path.relpath(path, self.top.folder)
        except ValueError:  # another drive (Windows)
            return str(path)

    def default(self, el: _Element):
        self.check_attrs(el, ("name", "value"))
        if el.children:
            self.fail(el.children[0], f"<{el.children[0].tag}> cannot appear inside <default>")
        name = el.attrs["name"]
        if not name:
            self.fail(el, "the parameter name is empty")
        if all(p.key != "$" + name for p in self.params):
            self.params.append(_Param(name, el.attrs["value"], used=True))
            self._sort_params()

    def unknown_tag(self, el: _Element):
        if el.tag in UNSUPPORTED_TAGS:
            self.fail(el, UNSUPPORTED_TAGS[el.tag])
        if el.tag in TRANSFORM_OPS:
            self.fail(el, f"<{el.tag}> can only appear inside a <transform>")
        if el.tag == "scene":
            self.fail(el, "<scene> can only be the root element")
        self.fail(el, f"unknown element <{el.tag}> (supported: {', '.join(ALL_TAGS)})")

    def version(self, root: _Element):
        """The root's ``version``: three numbers (Mitsuba's util::Version); stored on its file."""
        version = root.attrs["version"].strip()
        m = _VERSION_RE.fullmatch(version)
        if not m:
            self.fail(root, f'invalid version "{root.attrs["version"]}" (expected three numbers, e.g. "3.0.0")')
        root.file.version = tuple(int(g) for g in m.groups())

    def scene(self, root: _Element) -> XmlDict:
        self.substitute(root)
        if root.tag != "scene":
            self.fail(root, f"the root element must be <scene version=\"3.0.0\">, not <{root.tag}>")
        self.check_attrs(root, ("version",))
        self.version(root)
        node = self.object(root, "scene")
        unused = [p.key[1:] for p in self.params if not p.used]
        if unused:
            raise SceneError(self.source, "", f"parameter(s) {', '.join(sorted(unused))} given but not used "
                                              f"by the scene (no $name refers to them)")
        node.search_paths = list(self.resolver)
        return node


def parse_file(path: str | os.PathLike, params: dict | None = None) -> XmlDict:
    """Parse a Mitsuba 3 XML scene file into a Mitsuba-shaped dict (an :class:`XmlDict`).

    The result's ``search_paths`` are the folders mesh and texture filenames are looked up in
    (see :func:`resolve_file`).
    """
    source = str(path)
    try:
        data = Path(path).read_bytes()
    except OSError as e:
        raise SceneError(source, "", f"cannot read the file ({e.strerror or type(e).__name__})") from None
    top = _File(Path(path), "")
    root = _parse_tree(data, source, top)
    return _Converter(source, params or {}, top).scene(root)
