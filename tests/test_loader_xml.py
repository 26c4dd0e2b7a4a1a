"""The XML layer: <include>, <path>, <spectrum>, scene versions (Mitsuba 3.9's parser), and spectra -> RGB.

End to end through ``load_file`` where the builder consumes the result; through ``parse_file`` (the
Mitsuba-shaped dict) and ``spectrum_to_rgb`` where it does not yet (spectra, ``<path>`` mesh lookup).
Expected colours were computed with Mitsuba 3.9.1 (see ``MITSUBA_SPECTRA``); no Mitsuba is needed here.
"""

from __future__ import annotations

import dataclasses
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from pathtracer.errors import SceneError
from pathtracer.loader import load_file
from pathtracer.loader_xml import MAX_INCLUDE_DEPTH, XmlDict, _camel_to_snake, parse_file, resolve_file
from pathtracer.scene import Material
from pathtracer.spectra import spectrum_list_to_srgb, spectrum_to_rgb, uniform_emitter_rgb

DATA = Path(__file__).resolve().parent / "data" / "xml"
SENSOR = '<sensor type="perspective"><float name="fov" value="45"/></sensor>'


def write(path: Path, text: str) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


def scene_xml(body: str, version: str = "3.0.0", sensor: str = SENSOR) -> str:
    return f'<scene version="{version}">\n{sensor}\n{body}\n</scene>\n'


def assert_same(a, b, path: str = "scene"):
    """Field-by-field equality of two Scenes (numpy arrays compared exactly); ``source`` is ignored."""
    if dataclasses.is_dataclass(a):
        assert type(a) is type(b), path
        for f in dataclasses.fields(a):
            if f.name != "source":
                assert_same(getattr(a, f.name), getattr(b, f.name), f"{path}.{f.name}")
    elif isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        np.testing.assert_array_equal(a, b, err_msg=path)
    elif isinstance(a, (list, tuple)):
        assert len(a) == len(b), path
        for i, (x, y) in enumerate(zip(a, b)):
            assert_same(x, y, f"{path}[{i}]")
    else:
        assert a == b, (path, a, b)


def check_error(err: SceneError, path: Path, element: str, problem: str):
    msg = str(err)
    assert "\n" not in msg, msg
    assert msg.startswith(f"{path}: "), msg
    assert element in err.element, (element, msg)
    assert problem in err.problem, (problem, msg)


def load_error(path: Path, **params) -> SceneError:
    with pytest.raises(SceneError) as e:
        load_file(path, **params)
    return e.value


# ---------------------------------------------------------------------------------------------
# <include>


def test_include_loads_the_same_scene_as_its_flat_twin():
    # inc/parts.xml (a <scene>: merged in place) holds a bsdf, an obj shape and a nested include of
    # deeper/leaf.xml; inc/white.xml (a <bsdf> root) becomes the rectangle's bsdf.
    assert_same(load_file(DATA / "include_main.xml"), load_file(DATA / "include_flat.xml"))


def test_include_defaults_are_shared_first_wins_and_params_beat_them():
    s = load_file(DATA / "include_main.xml")
    red = Material("diffuse", (0.25, 0.1, 0.1))  # the includer's r=0.25 beats inc/parts.xml's r=0.75
    assert s.materials[s.meshes[0].material] == red and s.materials[s.spheres[0].material] == red
    assert s.spheres[0].radius == 0.5  # $g comes from a <default> inside the included file
    s = load_file(DATA / "include_main.xml", r=0.5, g=0.75)  # passed parameters beat every <default>
    assert s.materials[s.spheres[0].material] == Material("diffuse", (0.5, 0.1, 0.1))
    assert s.spheres[0].radius == 0.75


def test_include_elements_remember_their_file():
    d = parse_file(DATA / "include_main.xml")
    assert d["red"].where == 'inc/parts.xml line 4 <bsdf type="diffuse" id="red">'
    assert d["tetra"].prop_where["filename"] == 'inc/parts.xml line 9 <string name="filename">'
    assert d["box"].where == 'inc/deeper/leaf.xml line 3 <shape type="cube" id="box">'
    assert d["panel"]["bsdf"].where == 'inc/white.xml line 1 <bsdf type="diffuse">'
    assert d["panel"].prop_where["bsdf"] == 'line 15 <include name="bsdf" filename="inc/white.xml">'
    assert d["ball"].where == 'line 18 <shape type="sphere" id="ball">'
    # document order: the merged children sit where the <include> was
    assert [k for k in d if k != "type"] == ["_arg_0", "red", "tetra", "box", "panel", "ball"]
    # the obj in inc/parts.xml names tetra.obj, found next to the top-level scene (Mitsuba resolves
    # mesh files after parsing, with the top-level resolver)
    assert (DATA / "tetra.obj").is_file() and not (DATA / "inc" / "tetra.obj").exists()


def test_error_in_included_file_names_that_file(tmp_path):
    write(tmp_path / "sub" / "shapes.xml", '<scene version="3.0.0">\n'
          '  <shape type="sphere">\n    <float name="radious" value="1"/>\n  </shape>\n</scene>\n')
    main = write(tmp_path / "main.xml", scene_xml('<include filename="sub/shapes.xml"/>'))
    check_error(load_error(main), main, 'sub/shapes.xml line 2 <shape type="sphere">',
                'property "radious" is not supported')
    write(tmp_path / "sub" / "shapes.xml", '<scene version="3.0.0">\n\n  <shape type="sphere" foo="1"/>\n</scene>')
    check_error(load_error(main), main, 'sub/shapes.xml line 3 <shape type="sphere">', 'unexpected attribute "foo"')


def test_included_scene_and_object_inside_an_object(tmp_path):
    write(tmp_path / "mat_scene.xml", '<scene version="3.0.0"><bsdf type="diffuse">'
          '<rgb name="reflectance" value="0.2 0.3 0.4"/></bsdf></scene>')
    write(tmp_path / "mat.xml", '<bsdf version="3.0.0" type="conductor"/>')
    main = write(tmp_path / "main.xml", scene_xml(
        '<shape type="sphere"><include filename="mat_scene.xml"/></shape>'
        '<shape type="sphere"><include filename="mat.xml"/></shape>'))
    s = load_file(main)
    assert [s.materials[sp.material] for sp in s.spheres] == [Material("diffuse", (0.2, 0.3, 0.4)),
                                                              Material("mirror", (1.0, 1.0, 1.0))]
    d = parse_file(main)
    assert set(d["_arg_1"]) == {"type", "_arg_0"} and set(d["_arg_2"]) == {"type", "_arg_0"}


def test_nested_include_is_relative_to_the_including_file(tmp_path):
    write(tmp_path / "a" / "b" / "leaf.xml", '<scene version="3.0.0"><shape type="cube" id="leaf"/></scene>')
    write(tmp_path / "a" / "mid.xml", '<scene version="3.0.0"><include filename="b/leaf.xml"/></scene>')
    write(tmp_path / "b" / "leaf.xml", '<scene version="3.0.0"><shape type="sphere" id="wrong"/></scene>')
    main = write(tmp_path / "main.xml", scene_xml('<include filename="a/mid.xml"/>'))
    d = parse_file(main)
    assert "leaf" in d and "wrong" not in d
    assert d["leaf"].where == 'a/b/leaf.xml line 1 <shape type="cube" id="leaf">'


def test_default_from_include_is_visible_only_after_it(tmp_path):
    write(tmp_path / "defs.xml", '<scene version="3.0.0"><default name="rad" value="2"/></scene>')
    after = write(tmp_path / "after.xml", scene_xml(
        '<include filename="defs.xml"/><shape type="sphere"><float name="radius" value="$rad"/></shape>'))
    assert load_file(after).spheres[0].radius == 2.0
    before = write(tmp_path / "before.xml", scene_xml(
        '<shape type="sphere"><float name="radius" value="$rad"/></shape><include filename="defs.xml"/>'))
    check_error(load_error(before), before, '<float name="radius">', 'undefined parameter "$rad"')
    # substitution applies to the include's filename too
    via = write(tmp_path / "via.xml", scene_xml('<default name="f" value="defs"/><include filename="$f.xml"/>'
                                                '<shape type="sphere"><float name="radius" value="$rad"/></shape>'))
    assert load_file(via).spheres[0].radius == 2.0


def test_unused_parameter_is_checked_across_includes(tmp_path):
    write(tmp_path / "sub.xml", '<scene version="3.0.0"><shape type="sphere">'
          '<float name="radius" value="$rad"/></shape></scene>')
    main = write(tmp_path / "main.xml", scene_xml('<include filename="sub.xml"/>'))
    assert load_file(main, rad=3).spheres[0].radius == 3.0
    check_error(load_error(main, rad=3, other=1), main, "", "parameter(s) other given but not used")


def test_duplicate_id_across_files(tmp_path):
    write(tmp_path / "sub.xml", '<scene version="3.0.0"><bsdf type="diffuse" id="m"/></scene>')
    main = write(tmp_path / "main.xml", scene_xml('<bsdf type="diffuse" id="m"/><include filename="sub.xml"/>'))
    check_error(load_error(main), main, 'sub.xml line 1 <bsdf type="diffuse" id="m">', '"m" is given twice')


def _chain(tmp_path: Path, n: int) -> Path:
    """main.xml -> f1.xml -> ... -> f{n}.xml (n includes deep)."""
    for i in range(1, n + 1):
        inner = f'<include filename="f{i + 1}.xml"/>' if i < n else '<shape type="sphere"/>'
        write(tmp_path / f"f{i}.xml", f'<scene version="3.0.0">{inner}</scene>')
    return write(tmp_path / "main.xml", scene_xml('<include filename="f1.xml"/>'))


def test_include_depth_limit_is_mitsubas(tmp_path):
    ok = _chain(tmp_path / "ok", MAX_INCLUDE_DEPTH - 1)  # 15 files in all, as Mitsuba allows
    assert len(load_file(ok).spheres) == 1
    deep = _chain(tmp_path / "deep", MAX_INCLUDE_DEPTH)
    check_error(load_error(deep), deep, 'f14.xml line 1 <include filename="f15.xml">', "nested more than 14 deep")


INCLUDE_ERRORS = [
    # (files {name: text}, element, problem); main.xml includes as given
    ({"main.xml": scene_xml('<include filename="nope.xml"/>')},
     'line 3 <include filename="nope.xml">', 'included file "nope.xml" not found (looked in: '),
    ({"main.xml": scene_xml('<include filename="main.xml"/>')},
     'line 3 <include filename="main.xml">', "include cycle: main.xml -> main.xml"),
    ({"main.xml": scene_xml('<include filename="a.xml"/>'),
      "a.xml": '<scene version="3.0.0">\n<include filename="sub/b.xml"/></scene>',
      "sub/b.xml": '<scene version="3.0.0"><include filename="../a.xml"/></scene>'},
     'sub/b.xml line 1 <include filename="../a.xml">', "include cycle: main.xml -> a.xml -> sub/b.xml -> a.xml"),
    ({"main.xml": scene_xml('<include filename="bad.xml"/>'),
      "bad.xml": '<scene version="3.0.0">\n  <shape type="sphere">\n</scene>'},
     "bad.xml line 3", 'malformed XML: mismatched tag (column 3) (included by line 3 <include filename="bad.xml">)'),
    ({"main.xml": scene_xml('<include filename="empty.xml"/>'), "empty.xml": ""},
     "empty.xml", "the file is empty"),
    ({"main.xml": scene_xml('<include filename="nov.xml"/>'), "nov.xml": "<scene/>"},
     "nov.xml line 1 <scene>", 'missing required attribute "version"'),
    ({"main.xml": scene_xml('<include filename="v.xml"/>'), "v.xml": '<scene version="3.0"/>'},
     "v.xml line 1 <scene>", 'invalid version "3.0"'),
    ({"main.xml": scene_xml('<include filename="p.xml"/>'),
      "p.xml": '<scene version="3.0.0"><float name="radius" value="2"/></scene>'},
     'p.xml line 1 <float name="radius">', "at the root of an included <scene> is dropped by Mitsuba"),
    ({"main.xml": scene_xml('<bsdf type="diffuse" id="m"/><shape type="sphere"><include filename="r.xml"/></shape>'),
      "r.xml": '<scene version="3.0.0"><ref id="m"/></scene>'},
     'r.xml line 1 <ref id="m">', "at the root of an included <scene> is dropped by Mitsuba"),
    ({"main.xml": scene_xml('<include filename="rgb.xml"/>'), "rgb.xml": '<rgb version="3.0.0" name="x" value="1"/>'},
     'rgb.xml line 1 <rgb name="x">', "the root of an included file must be <scene> or an object"),
    ({"main.xml": scene_xml('<include filename="b.xml"/>'), "b.xml": '<bsdf type="diffuse"/>'},
     'b.xml line 1 <bsdf type="diffuse">', 'missing required attribute "version"'),
    ({"main.xml": scene_xml('<include/>')}, "line 3 <include>", 'missing required attribute "filename"'),
    ({"main.xml": scene_xml('<include filename="x.xml" id="a"/>')}, "line 3 <include", 'unexpected attribute "id"'),
    ({"main.xml": scene_xml('<include filename="x.xml"><float name="a" value="1"/></include>'), "x.xml": ""},
     'line 3 <float name="a">', "cannot appear inside <include>"),
]


@pytest.mark.parametrize("files,element,problem", INCLUDE_ERRORS, ids=[c[2][:40] for c in INCLUDE_ERRORS])
def test_include_errors(tmp_path, files, element, problem):
    for name, text in files.items():
        write(tmp_path / name, text)
    main = tmp_path / "main.xml"
    check_error(load_error(main), main, element, problem)


# ---------------------------------------------------------------------------------------------
# <path> and file resolution


def test_path_search_paths_and_resolve_file(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    scene_dir = tmp_path / "scene"
    for d in ("a", "b"):
        (scene_dir / d).mkdir(parents=True)
    main = write(scene_dir / "main.xml", scene_xml('<path value="a"/><path value="b"/>'))
    paths = parse_file(main).search_paths
    # last-declared <path> first, then the scene's folder, then the working directory
    assert paths == [scene_dir / "b", scene_dir / "a", scene_dir, tmp_path]
    write(scene_dir / "a" / "m.obj", "")
    assert resolve_file("m.obj", paths) == scene_dir / "a" / "m.obj"
    write(scene_dir / "m.obj", "")
    assert resolve_file("m.obj", paths) == scene_dir / "a" / "m.obj"  # a <path> beats the scene folder
    write(scene_dir / "b" / "m.obj", "")
    assert resolve_file("m.obj", paths) == scene_dir / "b" / "m.obj"
    write(tmp_path / "only_cwd.obj", "")
    assert resolve_file("only_cwd.obj", paths) == tmp_path / "only_cwd.obj"
    assert resolve_file("missing.obj", paths) == scene_dir / "b" / "missing.obj"  # first candidate
    assert resolve_file("missing.obj", []) == Path("missing.obj")
    assert resolve_file(str(tmp_path / "x" / "abs.obj"), paths) == tmp_path / "x" / "abs.obj"


def test_search_paths_without_path_tags(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    main = write(tmp_path / "s" / "main.xml", scene_xml(""))
    assert parse_file(main).search_paths == [tmp_path / "s", tmp_path]
    assert parse_file(Path("s") / "main.xml").search_paths == [Path("s"), tmp_path]


def test_path_falls_back_to_the_resolver(tmp_path, monkeypatch):
    # not next to the XML file, so Mitsuba tries the resolver: here the working directory
    monkeypatch.chdir(tmp_path)
    (tmp_path / "meshes").mkdir()
    main = write(tmp_path / "s" / "main.xml", scene_xml('<path value="meshes"/>'))
    assert parse_file(main).search_paths[0] == tmp_path / "meshes"


def test_path_in_an_included_file_does_not_reach_mesh_lookup(tmp_path):
    (tmp_path / "sub" / "alt").mkdir(parents=True)
    write(tmp_path / "sub" / "alt" / "s.spd", "400 0.5\n700 0.5\n")
    write(tmp_path / "sub" / "inc.xml", '<scene version="3.0.0"><path value="alt"/>'
          '<bsdf type="diffuse" id="m"><spectrum name="reflectance" filename="s.spd"/></bsdf></scene>')
    main = write(tmp_path / "main.xml", scene_xml('<include filename="sub/inc.xml"/>'))
    d = parse_file(main)
    # the included <path> served that file's own spectrum lookup ...
    assert d["m"]["reflectance"] == {"type": "spectrum", "wavelengths": [400.0, 700.0], "values": [0.5, 0.5]}
    # ... but, as in Mitsuba, never the top-level resolver
    assert tmp_path / "sub" / "alt" not in d.search_paths


def test_path_scene_data_is_consistent():
    d = parse_file(DATA / "path" / "scene.xml")
    assert d.search_paths[:2] == [DATA / "path" / "alt", DATA / "path"]
    assert resolve_file("tetra.obj", d.search_paths) == DATA / "path" / "alt" / "tetra.obj"
    assert not (DATA / "path" / "tetra.obj").exists()


def test_path_finds_a_mesh_end_to_end():
    s = load_file(DATA / "path" / "scene.xml")
    assert len(s.meshes) == 1 and len(s.meshes[0].faces) == 4


PATH_ERRORS = [
    ('<path value="nowhere"/>', 'line 3 <path>', 'folder "nowhere" not found (looked in: '),
    ('<path value=""/>', 'line 3 <path>', "the folder name is empty"),
    ('<path/>', 'line 3 <path>', 'missing required attribute "value"'),
    ('<shape type="sphere"><path value="."/></shape>', "line 3 <path>",
     "<path> can only be a direct child of the root <scene>"),
]


@pytest.mark.parametrize("body,element,problem", PATH_ERRORS, ids=[c[2][:40] for c in PATH_ERRORS])
def test_path_errors(tmp_path, body, element, problem):
    main = write(tmp_path / "main.xml", scene_xml(body))
    check_error(load_error(main), main, element, problem)


# ---------------------------------------------------------------------------------------------
# <spectrum>

PAIRS = {"type": "spectrum", "wavelengths": [400.0, 500.0, 600.0, 700.0], "values": [0.1, 0.5, 0.9, 0.2]}


def test_spectrum_dicts_from_xml():
    d = parse_file(DATA / "spectra" / "spectra.xml")
    assert d["pairs"]["reflectance"] == PAIRS
    assert d["file"]["reflectance"] == PAIRS  # refl.spd: comments and an empty line skipped
    assert d["uniform"]["reflectance"] == {"type": "spectrum", "value": 0.5}
    assert d["light"]["_arg_0"]["radiance"] == PAIRS
    assert d["pairs"].prop_where["reflectance"] == 'line 4 <spectrum name="reflectance">'
    for v in (d["pairs"]["reflectance"]["wavelengths"] + d["file"]["reflectance"]["values"]):
        assert type(v) is float


def test_spectrum_value_forms(tmp_path):
    main = write(tmp_path / "main.xml", scene_xml(
        '<bsdf type="diffuse" id="a"><spectrum name="reflectance" value="400:0.1,500:0.5 600:0.9,  700:0.2"/></bsdf>'
        '<bsdf type="diffuse" id="b"><spectrum name="reflectance" value=" 2e-1 "/></bsdf>'
        '<default name="s" value="450:1, 650:0"/>'
        '<bsdf type="diffuse" id="c"><spectrum name="reflectance" value="$s"/></bsdf>'))
    d = parse_file(main)
    assert d["a"]["reflectance"] == PAIRS
    assert d["b"]["reflectance"] == {"type": "spectrum", "value": 0.2}
    assert d["c"]["reflectance"] == {"type": "spectrum", "wavelengths": [450.0, 650.0], "values": [1.0, 0.0]}


def test_spectrum_file_in_included_file_uses_the_includers_folder(tmp_path):
    # Mitsuba quirk: the included file is parsed with the includer's folder in front of the resolver,
    # so its spectrum files are found there, not next to the included file.
    write(tmp_path / "sub" / "inc.xml", '<scene version="3.0.0"><bsdf type="diffuse" id="m">'
          '<spectrum name="reflectance" filename="s.spd"/></bsdf></scene>')
    main = write(tmp_path / "main.xml", scene_xml('<include filename="sub/inc.xml"/>'))
    write(tmp_path / "sub" / "s.spd", "400 1\n700 1\n")
    check_error(load_error(main), main, 'sub/inc.xml line 1 <spectrum name="reflectance" filename="s.spd">',
                'spectrum file "s.spd" not found (looked in: ')
    write(tmp_path / "s.spd", "400 0.25\n700 0.25\n")
    assert parse_file(main)["m"]["reflectance"]["values"] == [0.25, 0.25]


SPECTRUM_ERRORS = [
    ('value="500:0.5"', "at least 2 wavelength:value pairs (got 1)"),
    ('value="0.5 0.6"', '"0.5" in value="0.5 0.6" is not a wavelength:value pair'),
    ('value="400:0.1:3, 500:1"', '"400:0.1:3" in value="400:0.1:3, 500:1" is not a wavelength:value pair'),
    ('value="600:0.5, 500:0.2"', "wavelengths must increase strictly (500 follows 600)"),
    ('value="500:0.5, 500:0.2"', "wavelengths must increase strictly (500 follows 500)"),
    ('value="400:abc, 500:1"', 'value "abc" is not a number'),
    ('value="x:1, 500:1"', 'wavelength "x" is not a number'),
    ('value="400:nan, 500:1"', 'value "nan" is not a finite number'),
    ('value="inf"', 'value "inf" is not a finite number'),
    ('value="1e999"', 'value "1e999" is not a finite number'),
    ('value=""', 'needs either a non-empty "value" or a "filename" (not both)'),
    ('', 'missing required attribute "name"'),
    ('value="0.5" filename="a.spd"', 'needs either a non-empty "value" or a "filename" (not both)'),
    ('filename="nope.spd"', 'spectrum file "nope.spd" not found (looked in: '),
    ('value="0.5" foo="1"', 'unexpected attribute "foo"'),
    ('type="blackbody"', 'spectrum plugins (<spectrum type="blackbody">) are not supported'),
    ('type="d65"', 'spectrum plugins (<spectrum type="d65">) are not supported'),
]


@pytest.mark.parametrize("attrs,problem", SPECTRUM_ERRORS, ids=[c[1][:40] for c in SPECTRUM_ERRORS])
def test_spectrum_errors(tmp_path, attrs, problem):
    named = 'name="reflectance" ' if attrs else ""
    main = write(tmp_path / "main.xml", scene_xml(f'<bsdf type="diffuse"><spectrum {named}{attrs}/></bsdf>'))
    with pytest.raises(SceneError) as e:
        parse_file(main)
    check_error(e.value, main, "line 3 <spectrum", problem)


SPD_ERRORS = [
    ("400 0.5\n700\n", 'line 2: expected "wavelength value" (two finite numbers), got "700"'),
    ("# c\n400 0.5 1\n700 1\n", 'line 2: expected "wavelength value" (two finite numbers), got "400 0.5 1"'),
    ("400 0.5\n700 nan\n", 'line 2: expected "wavelength value"'),
    ("400, 0.5\n700 1\n", 'line 1: expected "wavelength value"'),
    ("# only a comment\n400 0.5\n", "at least 2 wavelength:value pairs (got 1)"),
    ("700 0.5\n400 0.5\n", "wavelengths must increase strictly (400 follows 700)"),
]


@pytest.mark.parametrize("text,problem", SPD_ERRORS, ids=[c[1][:40] for c in SPD_ERRORS])
def test_spectrum_file_errors(tmp_path, text, problem):
    spd = write(tmp_path / "s.spd", text)
    main = write(tmp_path / "main.xml", scene_xml(
        '<bsdf type="diffuse"><spectrum name="reflectance" filename="s.spd"/></bsdf>'))
    with pytest.raises(SceneError) as e:
        parse_file(main)
    check_error(e.value, main, 'line 3 <spectrum name="reflectance" filename="s.spd">', f'spectrum file "{spd}"')
    assert problem in e.value.problem, str(e.value)


def test_spectrum_file_accepts_trailing_comments_and_any_extension(tmp_path):
    write(tmp_path / "s.txt", "  # header\n400 0.5   # blue\n\n   \n700\t0.25\r\n")
    main = write(tmp_path / "main.xml", scene_xml(
        '<bsdf type="diffuse" id="m"><spectrum name="reflectance" filename="s.txt"/></bsdf>'))
    assert parse_file(main)["m"]["reflectance"] == {"type": "spectrum", "wavelengths": [400.0, 700.0],
                                                    "values": [0.5, 0.25]}


def test_spectrum_is_still_refused_where_a_plugin_is_given(tmp_path):
    main = write(tmp_path / "main.xml", scene_xml('<shape type="sphere"><spectrum type="srgb" name="x"/></shape>'))
    check_error(load_error(main), main, '<spectrum type="srgb" name="x">', "spectrum plugins")


# Mitsuba 3.9.1, scalar_rgb (llvm_ad_rgb gives the same): each spectrum put in a scene as
#   diffuse   <spectrum name="reflectance" value="..."/>  (bounded reflectance: D65-weighted, clipped to [0, 1])
#   area      <spectrum name="radiance" value="..."/>     (emitter: no D65, negatives clamped)
#   conductor <spectrum name="eta" value="..."/>          (unbounded: D65-weighted, negatives clamped)
# and read back with [float(x) for x in mi.traverse(scene)['<id>.reflectance.value']] (resp. radiance, eta).
MITSUBA_SPECTRA = {
    "400:0.1, 500:0.5, 600:0.9, 700:0.2": {
        "refl": (0.8338258266448975, 0.6891215443611145, 0.2652426064014435),
        "emit": (0.9743236899375916, 0.661608099937439, 0.22971083223819733),
        "eta": (0.8338258266448975, 0.6891215443611145, 0.2652426064014435)},
    "360:1, 830:1": {
        "refl": (0.9989852905273438, 0.9988737106323242, 0.998801589012146),
        "emit": (1.2048836946487427, 0.9482281804084778, 0.9092668294906616),
        "eta": (0.9989852905273438, 0.9988737106323242, 0.998801589012146)},
    "400:2, 700:2": {  # out of gamut as a reflectance: Mitsuba clips (and warns)
        "refl": (1.0, 1.0, 1.0),
        "emit": (2.3993871212005615, 1.899040699005127, 1.8068866729736328),
        "eta": (1.9906840324401855, 1.999512791633606, 1.9898182153701782)},
    "450:0.8, 550:0.1": {  # negative red: clamped to 0 everywhere
        "refl": (0.0, 0.19333577156066895, 0.4039459526538849),
        "emit": (0.0, 0.1792018860578537, 0.34467339515686035),
        "eta": (0.0, 0.19333577156066895, 0.4039459526538849)},
    "380:0.05, 480:0.9, 520:0.3, 610:0.6, 720:0.95, 800:0.0": {
        "refl": (0.6403607130050659, 0.41662731766700745, 0.6708971858024597),
        "emit": (0.7668535709381104, 0.3935772180557251, 0.5986114144325256),
        "eta": (0.6403607130050659, 0.41662731766700745, 0.6708971858024597)},
    "300:0.5, 900:0.5": {  # beyond the CIE range [360, 830]
        "refl": (0.4994926452636719, 0.4994368553161621, 0.499400794506073),
        "emit": (0.6024418473243713, 0.4741140902042389, 0.4546334147453308),
        "eta": (0.4994926452636719, 0.4994368553161621, 0.499400794506073)},
    "0.5": {  # uniform: a grey reflectance (Mitsuba's "uniform" 0.5), a purple-ish emitter
        "refl": (0.5, 0.5, 0.5),
        "emit": (0.6023969650268555, 0.4741455018520355, 0.4544580280780792),
        "eta": (0.5, 0.5, 0.5)},
    "0.25": {
        "refl": (0.25, 0.25, 0.25),
        "emit": (0.30119848251342773, 0.23707275092601776, 0.2272290140390396),
        "eta": (0.25, 0.25, 0.25)},
}


def _spectrum_dict(tmp_path: Path, value: str) -> dict:
    main = write(tmp_path / "main.xml", scene_xml(
        f'<bsdf type="diffuse" id="m"><spectrum name="reflectance" value="{value}"/></bsdf>'))
    return parse_file(main)["m"]["reflectance"]


@pytest.mark.parametrize("value", list(MITSUBA_SPECTRA))
def test_spectrum_to_rgb_matches_mitsuba(tmp_path, value):
    spec = _spectrum_dict(tmp_path, value)
    want = MITSUBA_SPECTRA[value]
    np.testing.assert_allclose(spectrum_to_rgb(spec, emitter=False), want["refl"], atol=1e-5, rtol=0)
    np.testing.assert_allclose(spectrum_to_rgb(spec, emitter=True), want["emit"], atol=1e-5, rtol=0)
    np.testing.assert_allclose(spectrum_to_rgb(spec, emitter=False, unbounded=True), want["eta"], atol=1e-5, rtol=0)
    assert all(type(c) is float for c in spectrum_to_rgb(spec, emitter=True))


def test_spectrum_file_gives_the_same_colour_as_the_pairs():
    d = parse_file(DATA / "spectra" / "spectra.xml")
    want = MITSUBA_SPECTRA["400:0.1, 500:0.5, 600:0.9, 700:0.2"]["refl"]
    np.testing.assert_allclose(spectrum_to_rgb(d["file"]["reflectance"], emitter=False), want, atol=1e-5, rtol=0)


def test_uniform_emitter_colour_is_xyz_to_srgb_of_one():
    # Mitsuba's "v * xyz_to_srgb(1, 1, 1)": the row sums of its XYZ -> sRGB matrix
    np.testing.assert_allclose(uniform_emitter_rgb(), (1.204794, 0.948291, 0.908916), atol=1e-6, rtol=0)


def test_clamp_false_shows_the_out_of_gamut_colour():
    raw = spectrum_list_to_srgb([400.0, 700.0], [2.0, 2.0], bounded=True, d65=True, clamp=False)
    np.testing.assert_allclose(raw, MITSUBA_SPECTRA["400:2, 700:2"]["eta"], atol=1e-5, rtol=0)
    raw = spectrum_to_rgb({"type": "spectrum", "wavelengths": [450, 550], "values": [0.8, 0.1]}, emitter=False,
                          clamp=False)
    assert raw[0] < 0  # Mitsuba warns "clamping out-of-gamut color [-0.16618, 0.193336, 0.403946]"
    np.testing.assert_allclose(raw, (-0.16618, 0.193336, 0.403946), atol=1e-5, rtol=0)


@pytest.mark.parametrize("spec,problem", [
    ({"type": "rgb", "value": [1, 1, 1]}, 'expected a {"type": "spectrum", ...} dict'),
    ({"type": "spectrum"}, 'either "value" or both "wavelengths" and "values"'),
    ({"type": "spectrum", "value": 1, "values": [1]}, 'either "value" or both'),
    ({"type": "spectrum", "value": "1"}, "value must be a number"),
    ({"type": "spectrum", "value": float("nan")}, "value must be finite"),
    ({"type": "spectrum", "wavelengths": [400], "values": [1]}, "at least 2"),
    ({"type": "spectrum", "wavelengths": [400, 500], "values": [1]}, "2 wavelengths but 1 values"),
    ({"type": "spectrum", "wavelengths": [500, 400], "values": [1, 1]}, "increase strictly"),
    ({"type": "spectrum", "wavelengths": [400, float("inf")], "values": [1, 1]}, "wavelength must be finite"),
    ({"type": "spectrum", "wavelengths": "400 500", "values": [1, 1]}, "must be lists of numbers"),
])
def test_spectrum_to_rgb_refuses_malformed_dicts(spec, problem):
    with pytest.raises(ValueError) as e:
        spectrum_to_rgb(spec, emitter=False)
    assert problem in str(e.value) and "\n" not in str(e.value)


def test_importing_spectra_builds_no_tables():
    code = ("import pathtracer.spectra as s; assert s._tables.cache_info().currsize == 0; "
            "assert len(s._CIE_X) == len(s._CIE_Y) == len(s._CIE_Z) == len(s._D65) == 95; "
            "s.spectrum_to_rgb({'type': 'spectrum', 'value': 1.0}, emitter=True); "
            "assert s._tables.cache_info().currsize == 1")
    subprocess.run([sys.executable, "-c", code], check=True, cwd=Path(__file__).resolve().parents[1])


# ---------------------------------------------------------------------------------------------
# scene versions


def test_camel_to_snake_is_mitsubas():
    cases = {"toWorld": "to_world", "fovAxis": "fov_axis", "sampleCount": "sample_count", "maxDepth": "max_depth",
             "intIOR": "int_ior", "extIOR": "ext_ior", "nearClip": "near_clip", "pixelFormat": "pixel_format",
             "cropOffsetX": "crop_offset_x", "fov": "fov", "_arg_0": "_arg_0", "ToWorld": "To_world",
             "already_snake": "already_snake", "fooBARbaz": "foo_barbaz", "a1B": "a1B"}
    assert {k: _camel_to_snake(k) for k in cases} == cases


def test_v1_scene_loads_like_its_3_0_twin():
    old, new = load_file(DATA / "v1_scene.xml"), load_file(DATA / "v1_twin.xml")
    assert_same(old, new)
    # and the upgrade did something: the non-default values came through
    assert (old.integrator.max_depth, old.integrator.rr_depth, old.integrator.hide_emitters) == (4, 3, True)
    assert (old.camera.fov_axis, old.camera.near_clip, old.camera.far_clip, old.spp) == ("y", 0.05, 500.0, 16)
    assert (old.width, old.height, old.rfilter.kind) == (40, 30, "tent")
    assert old.materials[old.meshes[1].material] == Material("diffuse", (0.3, 0.4, 0.5))
    assert old.meshes[1].normals is None  # faceNormals


def test_v1_property_names_in_the_dict():
    d = parse_file(DATA / "v1_scene.xml")
    assert set(d["_arg_1"]) == {"type", "fov", "fov_axis", "near_clip", "far_clip", "to_world", "_arg_0", "_arg_1"}
    assert d["grey"]["reflectance"] == {"type": "rgb", "value": [0.3, 0.4, 0.5]}
    assert d["_arg_1"].prop_where["fov_axis"] == 'line 11 <string name="fovAxis">'
    assert "grey" in d  # ids (and names derived from them) are not renamed


@pytest.mark.parametrize("version", ["2.0.0", "2.1.0", "3.0.0", "3.5.2", "4.0.0"])
def test_versions_2_and_up_are_not_upgraded(tmp_path, version):
    main = write(tmp_path / "main.xml", scene_xml('<integrator type="path"><integer name="maxDepth" value="3"/>'
                                                  '</integrator>', version))
    check_error(load_error(main), main, '<integrator type="path">', 'property "maxDepth" is not supported')


@pytest.mark.parametrize("version", ["0.5.0", "0.6.0", "1.0.0", "1.99.99"])
def test_versions_below_2_are_upgraded(tmp_path, version):
    main = write(tmp_path / "main.xml", scene_xml('<integrator type="path"><integer name="maxDepth" value="3"/>'
                                                  '</integrator>', version))
    assert load_file(main).integrator.max_depth == 3


def test_upgrade_is_per_file(tmp_path):
    # a 3.0 scene including a 0.x bsdf: only the 0.x file's names are upgraded
    write(tmp_path / "old.xml", '<bsdf version="0.6.0" type="diffuse">'
          '<rgb name="diffuseReflectance" value="0.1 0.2 0.3"/></bsdf>')
    main = write(tmp_path / "main.xml", scene_xml('<shape type="sphere"><include filename="old.xml"/></shape>'))
    s = load_file(main)
    assert s.materials[s.spheres[0].material] == Material("diffuse", (0.1, 0.2, 0.3))
    # a 0.x scene including a 3.0 file: that file's nodes are not upgraded
    write(tmp_path / "new.xml", '<integrator version="3.0.0" type="path"><integer name="maxDepth" value="3"/>'
          '</integrator>')
    old = write(tmp_path / "old_main.xml", scene_xml('<include filename="new.xml"/>', "0.6.0"))
    check_error(load_error(old), old, 'new.xml line 1 <integrator type="path">', 'property "maxDepth" is not supported')


def test_diffuse_reflectance_is_renamed_for_diffuse_only(tmp_path):
    main = write(tmp_path / "main.xml", scene_xml(
        '<bsdf type="conductor" id="c"><rgb name="diffuseReflectance" value="0.5"/></bsdf>', "0.6.0"))
    assert set(parse_file(main)["c"]) == {"type", "id", "diffuse_reflectance"}
    check_error(load_error(main), main, '<bsdf type="conductor" id="c">', 'property "diffuse_reflectance" is not')


V1_ERRORS = [
    ('<integrator type="path"><integer name="maxDepth" value="3"/><integer name="max_depth" value="2"/>'
     '</integrator>', '<integer name="max_depth">', '"max_depth" is given twice in line 3 <integrator type="path"> '
                                                    '(first at line 3 <integer name="maxDepth">)'),
    ('<integrator type="path"><integer name="max_depth" value="3"/><integer name="maxDepth" value="2"/>'
     '</integrator>', '<integer name="maxDepth">', '"max_depth" (written "maxDepth", renamed for a version < 2.0.0 '
                                                   'scene) is given twice'),
    ('<bsdf type="diffuse"><rgb name="reflectance" value="0.5"/><rgb name="diffuseReflectance" value="0.5"/></bsdf>',
     '<bsdf type="diffuse">', '"diffuse_reflectance" (renamed "reflectance" for a version < 2.0.0 scene) and '
                              '"reflectance" are both given'),
    ('<bsdf type="diffuse"><float name="uoffset" value="0.1"/></bsdf>', '<float name="uoffset">',
     '"uoffset" (a Mitsuba 0.x texture coordinate offset/scale, which Mitsuba 3 turns into "to_uv"): '
     'texture coordinate transforms are not supported'),
    ('<bsdf type="diffuse"><float name="vScale" value="2"/></bsdf>', '<float name="vScale">',
     '"v_scale" is not supported'),  # "vScale" becomes "v_scale", not "vscale": an ordinary unknown property
    ('<shape type="sphere"><float name="uscale" value="2"/></shape>', '<float name="uscale">',
     "texture coordinate transforms are not supported"),
]


@pytest.mark.parametrize("body,element,problem", V1_ERRORS, ids=[c[2][:40] for c in V1_ERRORS])
def test_v1_errors(tmp_path, body, element, problem):
    main = write(tmp_path / "main.xml", scene_xml(body, "0.6.0"))
    err = load_error(main)
    if "v_scale" in problem:  # the builder names the bsdf for an unknown property
        check_error(err, main, '<bsdf type="diffuse">', 'property "v_scale" is not supported')
    else:
        check_error(err, main, element, problem)


@pytest.mark.parametrize("version", ["3.0", "3", "", "a.b.c", "3.0.0.1", "3.0.x", "v3.0.0", "-1.0.0"])
def test_bad_version_strings(tmp_path, version):
    main = write(tmp_path / "main.xml", scene_xml("", version))
    check_error(load_error(main), main, "line 1 <scene>", f'invalid version "{version}" (expected three numbers')


def test_the_top_level_dict_is_an_xmldict_with_search_paths():
    d = parse_file(DATA / "include_main.xml")
    assert isinstance(d, XmlDict) and d.search_paths[0] == DATA
    assert d["red"].search_paths is None and os.path.isabs(d.search_paths[-1])
