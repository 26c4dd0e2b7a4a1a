"""Mitsuba 3 XML -> the Mitsuba-shaped dict that ``pathtracer.loader`` turns into a Scene.

Only the syntax lives here: expat builds a tiny element tree with line numbers, ``$name``
parameters are substituted as Mitsuba's parser does, property tags become Python values,
``<transform>`` blocks become 4x4 numpy matrices (each operation left-multiplies, in document
order) and ``<ref>`` becomes ``{'type': 'ref', 'id': ...}``. Plugin semantics (which properties a
plugin has, defaults, ranges) are checked once, on the dict, for XML and dict scenes alike.

Every dict built here is an :class:`XmlDict` that remembers where its element and each of its
properties came from, so the dict layer can name ``line 12 <shape type="sphere">`` in errors.
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
OBJECT_TAGS = {"integrator", "sensor", "film", "sampler", "rfilter", "bsdf", "shape", "emitter"}
# Mitsuba tags this renderer does not support at all, with a hint.
UNSUPPORTED_TAGS = {
    "texture": "textures are not supported (give colours as <rgb> or <float>)",
    "spectrum": "<spectrum> is not supported (give colours as <rgb> or <float>)",
    "medium": "participating media are not supported",
    "phase": "phase functions are not supported",
    "volume": "volumes are not supported",
    "field": "<field> is not supported",
    "include": "<include> is not supported (put everything in one file)",
    "alias": "<alias> is not supported",
    "path": "<path> is not supported (mesh filenames are relative to the scene file)",
}
PROPERTY_TAGS = {"float", "integer", "boolean", "string", "rgb", "point", "vector"}
TRANSFORM_OPS = {"translate", "rotate", "scale", "matrix", "lookat"}
ALL_TAGS = sorted(OBJECT_TAGS | PROPERTY_TAGS | {"scene", "ref", "transform", "default"})

_FLOAT_RE = re.compile(r"[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?")
_NONFINITE_RE = re.compile(r"[+-]?(nan|inf|infinity)", re.IGNORECASE)
_INT_RE = re.compile(r"[+-]?\d+")
_SPLIT_RE = re.compile(r"[\s,]+")
_VERSION_RE = re.compile(r"(\d+)\.(\d+)\.(\d+)")


class Point3(tuple):
    """A 3-vector written as <point> or <vector> (kept apart from colours, as Mitsuba does)."""


class XmlDict(dict):
    """A plugin dict built from an XML element; remembers where it and its properties were written."""

    where: str
    category: str
    prop_where: dict

    def __init__(self, where: str, category: str):
        super().__init__()
        self.where = where
        self.category = category
        self.prop_where = {}


@dataclass
class _Element:
    tag: str
    attrs: dict
    line: int
    children: list = field(default_factory=list)

    def describe(self) -> str:
        shown = " ".join(f'{k}="{self.attrs[k]}"' for k in ("type", "name", "id") if k in self.attrs)
        return f"line {self.line} <{self.tag}{' ' + shown if shown else ''}>"


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


def _parse_tree(data: bytes, source: str) -> _Element:
    if not data.strip():
        raise SceneError(source, "", "the file is empty (expected a Mitsuba XML <scene>)")
    if b"\0" in data:
        raise SceneError(source, "", "the file is binary data, not a Mitsuba XML scene")

    parser = xml.parsers.expat.ParserCreate()
    stack: list[_Element] = []
    roots: list[_Element] = []

    def start(tag, attrs):
        el = _Element(tag, dict(attrs), parser.CurrentLineNumber)
        (stack[-1].children if stack else roots).append(el)
        stack.append(el)

    def end(tag):
        stack.pop()

    def doctype(*args):
        raise SceneError(source, f"line {parser.CurrentLineNumber}", "<!DOCTYPE> declarations are not supported")

    parser.StartElementHandler = start
    parser.EndElementHandler = end
    parser.StartDoctypeDeclHandler = doctype
    try:
        parser.Parse(data, True)
    except xml.parsers.expat.ExpatError as e:
        msg = xml.parsers.expat.errors.messages.get(e.code, str(e))
        raise SceneError(source, f"line {e.lineno}", f"malformed XML: {msg} (column {e.offset + 1})") from None
    return roots[0]


class _Converter:
    """Walks the element tree in document order, as Mitsuba's parser does."""

    def __init__(self, source: str, params: dict):
        self.source = source
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
        arg_counter = 0
        for child in el.children:
            self.substitute(child)
            tag = child.tag
            if tag == "default":
                self.default(child)
                continue
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
            if name in ("type", "id"):
                self.fail(child, f'"{name}" is reserved and cannot be a property name')
            if tag in OBJECT_TAGS or tag == "ref":
                if not name:
                    name = child.attrs.get("id") if category == "scene" and tag != "ref" else None
                if not name:
                    name = f"_arg_{arg_counter}"
                    arg_counter += 1
            if name in node:
                self.fail(child, f'"{name}" is given twice in {el.describe()} (first at {node.prop_where[name]})')
            node[name] = value
            node.prop_where[name] = child.describe()
        return node

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

    def scene(self, root: _Element) -> XmlDict:
        self.substitute(root)
        if root.tag != "scene":
            self.fail(root, f"the root element must be <scene version=\"3.0.0\">, not <{root.tag}>")
        self.check_attrs(root, ("version",))
        version = root.attrs["version"].strip()
        m = _VERSION_RE.fullmatch(version)
        if not m:
            self.fail(root, f'invalid version "{root.attrs["version"]}" (expected e.g. "3.0.0")')
        if int(m.group(1)) < 2:
            self.fail(root, f'version "{version}" is Mitsuba 0.x syntax (camelCase names); '
                            f'write Mitsuba 3 syntax and version="3.0.0"')
        node = self.object(root, "scene")
        unused = [p.key[1:] for p in self.params if not p.used]
        if unused:
            raise SceneError(self.source, "", f"parameter(s) {', '.join(sorted(unused))} given but not used "
                                              f"by the scene (no $name refers to them)")
        return node


def parse_file(path: str | os.PathLike, params: dict | None = None) -> XmlDict:
    """Parse a Mitsuba 3 XML scene file into a Mitsuba-shaped dict (an :class:`XmlDict`)."""
    source = str(path)
    try:
        data = Path(path).read_bytes()
    except OSError as e:
        raise SceneError(source, "", f"cannot read the file ({e.strerror or type(e).__name__})") from None
    root = _parse_tree(data, source)
    return _Converter(source, params or {}).scene(root)
