"""Mitsuba 3's own gradient test configurations (src/integrators/tests/test_ad_integrators.py, v3.9): the scenes,
the parameter, the integrator depth and its error threshold (mean of |a - b| / max(|b|, 0.2)), as dicts that
either loader reads: ``T`` is ``pathtracer.transform.Transform`` for ours and ``mi.ScalarTransform4f`` for
Mitsuba's. Mitsuba renders them at 128x128 and 1024 spp; the references here are 64x64."""

from __future__ import annotations

RES = 64


def sensor(T) -> dict:
    return {"type": "perspective", "to_world": T().look_at(origin=[0, 0, 4], target=[0, 0, 0], up=[0, 1, 0]),
            "film": {"type": "hdrfilm", "rfilter": {"type": "box"}, "width": RES, "height": RES,
                     "sample_border": True, "pixel_format": "rgb", "component_format": "float32"}}


def configs(T) -> dict[str, dict]:
    """name -> {"scene": dict, "key": str, "max_depth": int, "threshold": float (Mitsuba's mean threshold)}."""
    side = T().translate([1.25, 0.0, 1.0]) @ T().rotate([0, 1, 0], -90)
    return {
        "diffuse_albedo": {"key": "plane.bsdf.reflectance.value", "max_depth": 2, "threshold": 0.015, "scene": {
            "type": "scene", "sensor": sensor(T),
            "plane": {"type": "rectangle", "bsdf": {"type": "diffuse"}},
            "sphere": {"type": "sphere", "to_world": T().scale(0.25)},
            "light": {"type": "constant"}}},
        "diffuse_albedo_gi": {"key": "green.bsdf.reflectance.value", "max_depth": 3, "threshold": 0.04, "scene": {
            "type": "scene", "sensor": sensor(T),
            "plane": {"type": "rectangle"},
            "sphere": {"type": "sphere", "to_world": T().scale(0.25)},
            "green": {"type": "rectangle", "to_world": side,
                      "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.1, 1.0, 0.1]}}},
            "light": {"type": "constant", "radiance": 3.0}}},
        "area_light_radiance": {"key": "light.emitter.radiance.value", "max_depth": 2, "threshold": 0.02, "scene": {
            "type": "scene", "sensor": sensor(T),
            "plane": {"type": "rectangle",
                      "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [1.0, 1.0, 1.0]}}},
            "sphere": {"type": "sphere", "to_world": T().scale(0.25)},
            "light": {"type": "rectangle", "to_world": side,
                      "emitter": {"type": "area", "radiance": {"type": "rgb", "value": [3.0, 3.0, 3.0]}}}}},
        "directly_visible_area_light_radiance": {
            "key": "light.emitter.radiance.value", "max_depth": 2, "threshold": 0.02, "scene": {
                "type": "scene", "sensor": sensor(T),
                "light": {"type": "rectangle",
                          "emitter": {"type": "area", "radiance": {"type": "rgb", "value": [1.0, 1.0, 1.0]}}}}},
    }
