"""Gradients (pathtracer/gradients.py): parameter names as Mitsuba's traverse, forward-mode derivatives against
central differences with the same random numbers (exact up to float32 rounding: each path's estimate is a
polynomial in the reflectances and linear in the radiances once sampling is detached), the backward product
against the forward image, and the variant compiled only where gradients are asked for."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import pathtracer
from pathtracer.errors import RenderError

ROOT = Path(__file__).resolve().parents[1]
SCENES = ROOT / "scenes"
SPP = 16


def small(name: str, w: int = 32, h: int = 24):
    return pathtracer.load_file(str(SCENES / f"{name}.xml"), width=w, height=h)


def central_difference(scene, key: str, h: float, **kw) -> np.ndarray:
    params = pathtracer.traverse(scene)
    v = params[key]
    try:
        params[key] = v + h
        up = pathtracer.render(scene, spp=SPP, seed=7, progress=False, light_tracing=False, **kw)
        params[key] = v - h
        down = pathtracer.render(scene, spp=SPP, seed=7, progress=False, light_tracing=False, **kw)
    finally:
        params[key] = v
    return (up.astype(np.float64) - down) / (2 * h)


def test_parameters_are_named_as_mitsuba_traverse_names_them():
    scene = small("cornell_box")
    params = pathtracer.traverse(scene)
    assert set(params) == {"white.reflectance.value", "red.reflectance.value", "green.reflectance.value",
                           "block.reflectance.value", "light_bsdf.reflectance.value",
                           "light.emitter.radiance.value"}
    assert np.allclose(params["light.emitter.radiance.value"], scene.lights[0].radiance)
    params["red.reflectance.value"] = (0.1, 0.2, 0.3)
    assert params["red.reflectance.value"].tolist() == [0.1, 0.2, 0.3]
    assert "mirror.specular_reflectance.value" in pathtracer.traverse(small("open_sky"))
    with pytest.raises(RenderError, match=r"unknown or non-differentiable parameter 'blue.reflectance.value' "
                                          r"\(this scene has: block.reflectance.value"):
        params["blue.reflectance.value"]
    with pytest.raises(RenderError, match="three finite numbers >= 0"):
        params["red.reflectance.value"] = (-1.0, 0.0, 0.0)


@pytest.mark.parametrize("name,key", [
    ("cornell_box", "red.reflectance.value"),  # seen directly, in inter-reflections and in next-event estimates
    ("cornell_box", "white.reflectance.value"),  # several bounces on the same material: a polynomial of degree 3
    ("cornell_box", "light.emitter.radiance.value"),  # seen directly and in every next-event estimate: linear
    ("cornell_box_mirror", "red.reflectance.value"),  # also through the mirror sphere
    ("teapot_in_box", "red.reflectance.value"),  # a smooth-shaded mesh in the BVH
    ("open_sky", "mirror.specular_reflectance.value"),  # the mirror's own reflectance
])
def test_forward_gradient_equals_central_differences_with_the_same_random_numbers(name, key):
    scene = small(name)
    img, grad = pathtracer.render_forward(scene, key, spp=SPP, seed=7)
    assert np.array_equal(img, pathtracer.render(scene, spp=SPP, seed=7, progress=False, light_tracing=False))
    fd = central_difference(scene, key, 0.03)
    scale = np.abs(fd).max()
    assert scale > 1e-3  # the parameter does move the image
    # float32 rounding of the two images, divided by 2h, is the only difference (measured 2e-5 of the scale at
    # h = 0.03; a gradient that missed one factor, e.g. the next-event term, is off by tens of percent)
    assert np.abs(grad - fd).max() <= 2e-4 * scale, np.abs(grad - fd).max() / scale


def test_gradient_is_the_same_under_the_seed_roulette_rule():
    scene = small("cornell_box")
    scene.integrator.max_depth = 8  # roulette from the second bounce, with a fixed survival probability
    _, grad = pathtracer.render_forward(scene, "white.reflectance.value", spp=SPP, seed=7, rr="seed")
    # paths of up to 8 segments: a polynomial of higher degree, whose h^2 term in the central difference was
    # 1.2e-3 of the scale at h = 0.03; at h = 0.01 it is a ninth of that
    fd = central_difference(scene, "white.reflectance.value", 0.01, rr="seed")
    assert np.abs(grad - fd).max() <= 2e-4 * np.abs(fd).max()


@pytest.mark.parametrize("name", ["cornell_box", "cornell_box_mirror", "open_sky"])
def test_path_replay_equals_the_weighted_sum_of_the_forward_images(name):
    """Reverse against forward, same seed: path replay (every parameter from one render, each path traced twice)
    against one forward-mode render per parameter; the same derivatives summed in another order (measured
    1e-8-7e-8 apart, relative). Then against central differences of the loss sum(w * image)."""
    scene = small(name)
    rng = np.random.default_rng(0)
    w = rng.standard_normal((scene.height, scene.width, 3))
    keys = list(pathtracer.traverse(scene))
    back = pathtracer.render_backward(scene, keys, w, spp=SPP, seed=7, method="replay")
    for key in keys:
        _, g = pathtracer.render_forward(scene, key, spp=SPP, seed=7)
        expected = np.einsum("hwc,hwc->c", w, g.astype(np.float64))
        np.testing.assert_allclose(back[key], expected, rtol=1e-5, atol=1e-6 * np.abs(expected).max() + 1e-9)
    key = keys[0]
    fd = central_difference(scene, key, 0.01)
    np.testing.assert_allclose(back[key], np.einsum("hwc,hwc->c", w, fd), rtol=1e-3, atol=1e-3)


def test_backward_methods_agree_and_bad_input_is_refused():
    scene = small("cornell_box")
    w = np.ones((scene.height, scene.width, 3))
    keys = ["red.reflectance.value", "light.emitter.radiance.value"]
    a = pathtracer.render_backward(scene, keys, w, spp=SPP, seed=7)  # auto: replay for two keys
    b = pathtracer.render_backward(scene, keys, w, spp=SPP, seed=7, method="forward")
    c = pathtracer.render_backward(scene, keys[:1], w, spp=SPP, seed=7)  # auto: forward for one
    np.testing.assert_allclose(c[keys[0]], b[keys[0]], rtol=1e-12)
    for key in keys:
        np.testing.assert_allclose(a[key], b[key], rtol=1e-5)
    with pytest.raises(RenderError, match="grad_image must be"):
        pathtracer.render_backward(scene, keys, np.zeros((2, 2, 3)), spp=SPP)
    with pytest.raises(RenderError, match="unknown or non-differentiable parameter 'nope'"):
        pathtracer.render_backward(scene, ["nope"], w, spp=SPP)


def test_gradients_are_compiled_only_into_gradient_renders():
    from test_render_driver import generated_source

    scene = small("cornell_box", 8, 8)
    plain = pathtracer.Renderer(scene)
    grad = pathtracer.Renderer(scene, gradient=True)
    back = pathtracer.Renderer(scene, backward=True)
    src = generated_source(plain.kernel)
    assert "wp::address(var_accum_grad," not in src and "adj_tile" not in src
    assert "wp::address(var_accum_grad," in generated_source(grad.kernel)
    assert "adj_tile" in generated_source(back.kernel)
    assert len({id(plain.kernel), id(grad.kernel), id(back.kernel)}) == 3


def test_what_cannot_be_differentiated_is_refused():
    scene = small("cornell_box")
    with pytest.raises(RenderError, match="light tracing"):
        pathtracer.render_forward(scene, "red.reflectance.value", spp=4, light_tracing=True)
    plastic = pathtracer.load_dict({
        "type": "scene",
        "sensor": {"type": "perspective", "fov": 40, "film": {"type": "hdrfilm", "width": 8, "height": 8}},
        "ball": {"type": "sphere", "bsdf": {"type": "plastic", "id": "coat"}},
        "sky": {"type": "constant"},
    })
    with pytest.raises(RenderError, match="gradients are available on scenes of diffuse"):
        pathtracer.render_forward(plastic, "coat.reflectance.value", spp=4)


GRAD_REFS = ROOT / "tests" / "data" / "grad_refs"
GRAD_META = __import__("json").loads((GRAD_REFS / "refs.json").read_text())
# 16 batches: each pixel's squared difference over the batch variance is then a t^2 of 15 degrees of freedom, of
# mean 15 / 13 = 1.15 and standard deviation ~0.08 averaged over the image (~500 independent pixels under the
# filter): 1.5 is about four of those above the mean
BATCHES, BATCH_SPP = 16, 128


def batch_gradients(scene, key: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    gs = np.stack([pathtracer.render_forward(scene, key, spp=BATCH_SPP, seed=100 + b)[1]
                   for b in range(BATCHES)]).astype(np.float64)
    return gs.mean(axis=0), gs.var(axis=0, ddof=1) / BATCHES, gs


@pytest.mark.parametrize("name", sorted(GRAD_META["refs"]))
def test_forward_gradient_agrees_with_mitsuba_prb(name):
    """Against Mitsuba 3.9's prb forward-mode gradient images of the same files (examples/make_gradient_refs.py,
    16384 spp): within noise (mean squared difference over the summed variances near its expected 1.15, at most
    1.5; the image mean's z within 4), exact where both are noiseless, and Mitsuba's own
    test metric mean(|a - b| / max(|b|, 0.2)) far below its 0.05 (measured 0.0003-0.009). Mitsuba's own
    configurations (DiffuseAlbedo, DiffuseAlbedoGI, AreaLightRadiance, DirectlyVisibleAreaLightRadiance:
    tests/gradient_configs.py) are held to the thresholds Mitsuba's test gives each (0.015-0.04)."""
    info = GRAD_META["refs"][name]
    ref = pathtracer.read_image(GRAD_REFS / f"{name}.exr").astype(np.float64)
    ref_var = pathtracer.read_image(GRAD_REFS / f"{name}_var.exr").astype(np.float64)
    if "config" in info:  # Mitsuba's own test configurations, with its own threshold on its metric
        from gradient_configs import configs
        from pathtracer.transform import Transform

        c = configs(Transform)[info["config"]]
        scene = pathtracer.load_dict(c["scene"])
        scene.integrator.max_depth = c["max_depth"]
        threshold = c["threshold"]
    else:
        scene = pathtracer.load_file(str(ROOT / info["scene"]), width=GRAD_META["width"],
                                     height=GRAD_META["height"])
        threshold = 0.05  # (the issue's bound)
    ours, var, gs = batch_gradients(scene, info["key"])
    var_sum = var + ref_var
    noisy = var_sum > 0
    assert np.all(np.abs(ours - ref)[~noisy] <= 1e-5)
    chi = float(np.mean((ours - ref)[noisy] ** 2 / var_sum[noisy]))
    se = np.sqrt(gs.mean(axis=(1, 2, 3)).var(ddof=1) / BATCHES + ref_var.sum() / ref.size ** 2)
    z = (ours.mean() - ref.mean()) / se
    metric = float(np.mean(np.abs(ours - ref) / np.maximum(np.abs(ref), 0.2)))
    print(f"\n[prb ref] {name}: chi {chi:.3f}, image mean z {z:+.2f}, Mitsuba's metric {metric:.4f}")
    assert chi <= 1.5 and abs(z) <= 4 and metric <= threshold


def test_mitsuba_gradient_reference_tells_parameters_apart():
    """Control: the red wall's reference against our derivative for the white walls fails by far."""
    name = "cornell_box__red_reflectance"
    ref = pathtracer.read_image(GRAD_REFS / f"{name}.exr").astype(np.float64)
    ref_var = pathtracer.read_image(GRAD_REFS / f"{name}_var.exr").astype(np.float64)
    scene = pathtracer.load_file(str(SCENES / "cornell_box.xml"), width=GRAD_META["width"],
                                 height=GRAD_META["height"])
    ours, var, _ = batch_gradients(scene, "white.reflectance.value")
    noisy = (var + ref_var) > 0
    assert float(np.mean((ours - ref)[noisy] ** 2 / (var + ref_var)[noisy])) > 10


def test_a_warp_tape_differentiates_a_loss_kernel_through_the_render():
    """The Warp-native form: parameters in wp.arrays, the render recorded on a wp.Tape, a loss written as a Warp
    kernel, tape.backward() fills the parameters' .grad: with render_backward of the loss's image gradient."""
    import warp as wp

    from pathtracer.gradients import render_wp

    scene = small("cornell_box")
    target_img = pathtracer.render(scene, spp=64, seed=99, progress=False, light_tracing=False)
    target = wp.array(target_img.reshape(-1, 3), dtype=wp.vec3)

    @wp.kernel
    def l2(img: wp.array(dtype=wp.vec3), t: wp.array(dtype=wp.vec3), loss: wp.array(dtype=float)):
        i = wp.tid()
        d = img[i] - t[i]
        wp.atomic_add(loss, 0, wp.dot(d, d))

    rho = wp.array([wp.vec3(0.2, 0.5, 0.5)], dtype=wp.vec3, requires_grad=True)
    le = wp.array([wp.vec3(10.0, 10.0, 10.0)], dtype=wp.vec3, requires_grad=True)
    loss = wp.zeros(1, dtype=float, requires_grad=True)
    params = {"red.reflectance.value": rho, "light.emitter.radiance.value": le}
    with wp.Tape() as tape:
        img = render_wp(scene, params, spp=SPP, seed=1, seed_grad=2)
        wp.launch(l2, dim=img.shape[0], inputs=[img, target], outputs=[loss])
    tape.backward(loss)
    values = pathtracer.traverse(scene)
    assert values["red.reflectance.value"].tolist() == pytest.approx([0.2, 0.5, 0.5])
    image = img.numpy().reshape(target_img.shape)
    assert np.array_equal(image, pathtracer.render(scene, spp=SPP, seed=1, progress=False, light_tracing=False))
    expected = pathtracer.render_backward(scene, list(params), 2.0 * (image - target_img), spp=SPP, seed=2)
    for key, arr in params.items():
        np.testing.assert_allclose(arr.grad.numpy()[0], expected[key], rtol=1e-5)
    # the target is brighter in red (a redder wall, a stronger light): both gradients say to raise red
    assert rho.grad.numpy()[0, 0] < 0 and le.grad.numpy()[0, 0] < 0


def tiled_box(n: int = 2, depth: int = 14) -> "pathtracer.scene.Scene":
    """A closed box whose six walls are n x n tiles, each of its own diffuse colour, lit by a small light under
    the ceiling: paths bounce ``depth`` - 1 times and meet more materials than one pass's registers hold
    (kernels/adjoint.py: ADJ_CAP), so path replay's fallback runs next to the one-pass paths."""
    from pathtracer.transform import Transform as T

    rng = np.random.default_rng(3)
    d = {"type": "scene", "integrator": {"type": "path", "max_depth": depth, "rr_depth": 100},
         "sensor": {"type": "perspective", "fov": 80,
                    "to_world": T().look_at(origin=[0, 0, 0.9], target=[0, 0, -1], up=[0, 1, 0]),
                    "film": {"type": "hdrfilm", "width": 16, "height": 12, "rfilter": {"type": "box"}}},
         "light": {"type": "rectangle", "to_world": T().translate([0, 0.999, 0]) @ T().rotate([1, 0, 0], 90)
                   @ T().scale(0.2), "emitter": {"type": "area", "radiance": {"type": "rgb", "value": [20, 20, 20]}}}}
    walls = [T().rotate([1, 0, 0], -90) , T().rotate([1, 0, 0], 90), T(), T().rotate([0, 1, 0], 180),
             T().rotate([0, 1, 0], 90), T().rotate([0, 1, 0], -90)]  # floor, ceiling, back, front, left, right
    for w, rot in enumerate(walls):
        for i in range(n):
            for j in range(n):
                tile = (rot @ T().translate([(2 * i + 1) / n - 1, (2 * j + 1) / n - 1, -1]) @ T().scale(1 / n))
                d[f"tile_{w}_{i}_{j}"] = {"type": "rectangle", "to_world": tile, "bsdf": {
                    "type": "diffuse", "reflectance": {"type": "rgb", "value": (0.5 + 0.4 * rng.random(3)).tolist()}}}
    return pathtracer.load_dict(d)


def test_one_pass_adjoints_and_the_replay_of_paths_that_overflow_them_agree_with_forward_mode():
    """Most paths here meet more than ADJ_CAP materials (13 bounces among 24 tiles): they are replayed, the rest
    gather their adjoints in one pass; both must give forward mode's derivatives, summed in another order."""
    from kernels.adjoint import ADJ_CAP

    scene = tiled_box()
    assert len(scene.materials) > 2 * ADJ_CAP
    rng = np.random.default_rng(1)
    w = rng.standard_normal((scene.height, scene.width, 3))
    keys = list(pathtracer.traverse(scene))
    picked = [keys[0], keys[5], keys[17], "light.emitter.radiance.value"]
    back = pathtracer.render_backward(scene, picked, w, spp=8, seed=2, method="replay")
    for key in picked:
        _, g = pathtracer.render_forward(scene, key, spp=8, seed=2)
        expected = np.einsum("hwc,hwc->c", w, g.astype(np.float64))
        assert np.abs(expected).max() > 0
        np.testing.assert_allclose(back[key], expected, rtol=1e-5, atol=1e-6 * np.abs(expected).max())


def test_loss_gradient_from_split_halves_is_unbiased_and_its_methods_agree():
    """render_loss_gradient's halves A and B: each weighs the other's derivatives. The two methods sum the same
    derivatives in another order. For a quadratic loss the estimate is unbiased: its mean over 40 seeds at 4 spp
    matches 2/n sum (I - T) dI from two independent 1024-spp forward renders (I from one, dI from the other)
    within 4 standard errors; the same samples' product at 2 spp (w(A) dA, as one half alone), biased, does not."""
    scene = small("cornell_box", 32, 24)
    key = "red.reflectance.value"
    target = pathtracer.render(scene, spp=256, seed=99, progress=False, light_tracing=False) * 0.8

    def loss_grad(img):
        return 2.0 * (img.astype(np.float64) - target) / img.size

    keys = [key, "light.emitter.radiance.value"]
    img, f = pathtracer.render_loss_gradient(scene, keys, loss_grad, spp=8, seed=5, method="forward")
    img2, b = pathtracer.render_loss_gradient(scene, keys, loss_grad, spp=8, seed=5, method="replay")
    np.testing.assert_allclose(img, img2, rtol=1e-6, atol=1e-7)
    half = pathtracer.render(scene, spp=4, seed=5, progress=False, light_tracing=False)  # half A
    other = 2.0 * img.astype(np.float64) - half  # half B, from the other seed: a different image
    assert np.abs(other - half).max() > 0.01 and other.min() >= -1e-5
    for k in f:
        np.testing.assert_allclose(b[k], f[k], rtol=1e-5)

    ours, same = [], []
    for s in range(40):
        ours.append(pathtracer.render_loss_gradient(scene, key, loss_grad, spp=4, seed=s)[1][key])
        i2, d2 = pathtracer.render_forward(scene, key, spp=2, seed=1000 + s)
        same.append(np.einsum("hwc,hwc->c", loss_grad(i2), d2.astype(np.float64)))
    i_ref, _ = pathtracer.render_forward(scene, key, spp=1024, seed=7)
    _, d_ref = pathtracer.render_forward(scene, key, spp=1024, seed=8)
    ref = np.einsum("hwc,hwc->c", loss_grad(i_ref), d_ref.astype(np.float64))[0]
    for est, unbiased in ((np.array(ours), True), (np.array(same), False)):
        mean, se = est[:, 0].mean(), est[:, 0].std(ddof=1) / np.sqrt(len(est))
        assert (abs(mean - ref) <= 4 * se) == unbiased, (unbiased, mean, se, ref)
    with pytest.raises(RenderError, match="spp must be an integer >= 2"):
        pathtracer.render_loss_gradient(scene, key, loss_grad, spp=1)
    with pytest.raises(RenderError, match="loss_grad must return"):
        pathtracer.render_loss_gradient(scene, key, lambda img: np.zeros(3), spp=2)
