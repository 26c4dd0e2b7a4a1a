"""Gradients of a rendered image with respect to the scene's reflectances and light radiances.

Parameters are named as Mitsuba's ``mi.traverse`` names them: ``red.reflectance.value`` for a diffuse bsdf of id
``red``, ``mirror.specular_reflectance.value`` for a mirror (Mitsuba's conductor of material "none"), and
``light.emitter.radiance.value`` for the area emitter of a rectangle of id ``light``.

Forward mode carries the derivatives along each path beside its radiance (kernels/integrator.py, the
``gradient`` variant): d beta and dL, exact for the path as sampled. Reverse mode (the ``backward`` variant)
gathers every parameter's adjoint in one pass: each path keeps, per material it meets, the sum of 1 / rho over
its vertices there and the radiance gathered under it (kernels/adjoint.py), and adds its share once at its end;
a path that meets more parameters than those registers hold is traced again with its radiance known, as path
replay backpropagation does (Vicini et al. 2021: at every vertex the radiance still to come, over the vertex's
reflectance, goes into that material's adjoint; at every emitter hit and light sample, the throughput into that
light's). ``render_loss_gradient`` gives an image and a loss gradient from one set of samples split into two
independent halves, each weighing the other's derivatives. Sampling is detached, as in Mitsuba's
``prb``: the directions, light samples and roulette's survival probability do not move with the parameter, so
the estimate of every path is a polynomial in the reflectances and linear in the radiances, and its derivative
is taken exactly (tests/test_gradients.py checks it against central differences with the same random numbers).
Memory is O(1) in the path length: nothing is stored per vertex.

Not differentiable (yet): geometry (it needs the boundary terms of the visibility changes: interior derivatives
alone are badly biased), textures, glossy materials (plastic, rough conductors and plastics), and emitters other
than parallelograms. The channels are independent (RGB: the red reflectance moves only the red image), so the
forward image with the tangent 1 in every channel is also each channel's own derivative, and a backward product
with a weight image is one sum per channel.
"""

from __future__ import annotations

import dataclasses
from collections.abc import MutableMapping
from dataclasses import dataclass

import numpy as np

from pathtracer.errors import RenderError

KINDS = {"diffuse": "reflectance", "mirror": "specular_reflectance"}


@dataclass(frozen=True)
class Param:
    """Where a parameter lives: a material's ``rgb`` (``kind`` "material") or a parallelogram light's radiance."""

    kind: str
    index: int


def parameters(scene) -> dict[str, Param]:
    """The differentiable parameters of ``scene``, by Mitsuba's names."""
    out: dict[str, Param] = {}
    for i, m in enumerate(scene.materials):
        if m.name and m.kind in KINDS and m.texture < 0:
            out[f"{m.name}.{KINDS[m.kind]}.value"] = Param("material", i)
            if m.twosided:  # Mitsuba nests the bsdf in a twosided one: both names work
                out[f"{m.name}.brdf_0.{KINDS[m.kind]}.value"] = Param("material", i)
    for mesh in scene.meshes:
        if mesh.light >= 0 and mesh.name:
            out[f"{mesh.name}.emitter.radiance.value"] = Param("light", mesh.light)
    return out


class SceneParameters(MutableMapping):
    """``traverse(scene)``: key -> the parameter's current value, numpy (3,); assigning one changes the scene
    (render it again to see the change)."""

    def __init__(self, scene):
        self.scene = scene
        self.params = parameters(scene)

    def __getitem__(self, key: str) -> np.ndarray:
        p = self._param(key)
        if p.kind == "material":
            return np.array(self.scene.materials[p.index].rgb, dtype=np.float64)
        return np.array(self.scene.lights[p.index].radiance, dtype=np.float64)

    def __setitem__(self, key: str, value) -> None:
        p = self._param(key)
        v = np.broadcast_to(np.asarray(value, dtype=np.float64), (3,))
        if not (np.all(np.isfinite(v)) and np.all(v >= 0)):
            raise RenderError(f"{key}: a value must be three finite numbers >= 0, got {np.asarray(value).tolist()}")
        rgb = tuple(float(x) for x in v)
        if p.kind == "material":
            self.scene.materials[p.index] = dataclasses.replace(self.scene.materials[p.index], rgb=rgb)
        else:
            self.scene.lights[p.index] = dataclasses.replace(self.scene.lights[p.index], radiance=rgb)

    def __delitem__(self, key):
        raise RenderError("scene parameters cannot be removed")

    def __iter__(self):
        return iter(self.params)

    def __len__(self) -> int:
        return len(self.params)

    def _param(self, key: str) -> Param:
        return _lookup(self.params, key)


def _lookup(params: dict[str, Param], key: str) -> Param:
    """``params[key]``, or a one-line RenderError naming what the scene has."""
    p = params.get(key)
    if p is None:
        known = ", ".join(sorted(params)) or "none"
        raise RenderError(f"unknown or non-differentiable parameter {key!r} (this scene has: {known})")
    return p


def traverse(scene) -> SceneParameters:
    """The scene's differentiable parameters, readable and assignable by name (Mitsuba's ``mi.traverse``)."""
    return SceneParameters(scene)


def _with_sampler(opts: dict, spp: int) -> dict:
    """``opts`` with the sampler a render of ``spp`` passes gets by default where none is asked for (as ``render``:
    pathtracer.render.default_sampler), so that a gradient and a render of the same seed and spp match."""
    from pathtracer.render import default_sampler

    if opts.get("sampler") is None:
        opts = {**opts, "sampler": default_sampler(spp, opts.get("replicates"))}
    return opts


def _renderer(scene, opts: dict, backward: bool = False):
    """A forward-mode (``gradient``) or path-replay (``backward``) renderer of ``scene`` with ``opts``."""
    from pathtracer.render import Renderer

    if opts.get("light_tracing"):
        raise RenderError("gradients are not available with light tracing")
    opts = {k: v for k, v in opts.items() if k != "light_tracing"}
    return Renderer(scene, gradient=not backward, backward=backward, light_tracing=False, **opts)


def _other_seed(seed: int) -> int:
    """A second seed, for samples independent of ``seed``'s (a fixed odd-multiplier hash: any other value would do)."""
    return (seed * 0x9E3779B1 + 0x632BE5AB) % 2**32


def _keys_and_method(scene, keys, method: str) -> tuple[list[str], str, dict]:
    """The keys as a list, the method with "auto" decided (forward for one key, replay for more), and the scene's
    parameters, every key checked against them (one-line errors)."""
    keys = [keys] if isinstance(keys, str) else list(keys)
    if method not in ("auto", "replay", "forward"):
        raise RenderError(f"unknown backward method {method!r} (auto, replay or forward)")
    if method == "auto":
        method = "forward" if len(keys) == 1 else "replay"
    params = parameters(scene)
    for key in keys:
        _lookup(params, key)
    return keys, method, params


def _adjoint_of(params: dict, key: str, rgb: np.ndarray, rad: np.ndarray) -> np.ndarray:
    """``key``'s row of a backward renderer's adjoints (materials ``rgb``, lights ``rad``)."""
    p = params[key]
    return (rgb if p.kind == "material" else rad)[p.index].copy()


def _forward(r, key: str, params: dict, spp: int, seed: int):
    p = _lookup(params, key)
    r.grad_material = p.index if p.kind == "material" else -1
    r.grad_light = p.index if p.kind == "light" else -1
    sums = r.render_passes(seed=seed, first_pass=0, count=spp)
    grad = (sums.grad_sum / max(sums.passes, 1)).astype(np.float32)
    return sums.mean, grad


def render_forward(scene, key: str, spp: int | None = None, seed: int | None = None, **opts):
    """(image, gradient image): the render and d image / d theta for parameter ``key``, the tangent 1 in each of its
    three channels (as Mitsuba's ``dr.forward``); float32 (H, W, 3) each. ``opts``: as ``Renderer``'s."""
    spp = scene.spp if spp is None else spp
    seed = scene.sampler_seed if seed is None else seed
    opts = _with_sampler(opts, spp)
    r = _renderer(scene, opts)
    try:
        return _forward(r, key, parameters(scene), spp, seed)
    finally:
        r.close()


def render_backward(scene, keys, grad_image, spp: int | None = None, seed: int | None = None,
                    method: str = "auto", **opts) -> dict[str, np.ndarray]:
    """key -> (3,) numpy: the sum over pixels of ``grad_image`` times d image / d theta, per channel of theta (the
    adjoint of ``render_forward`` for a loss whose gradient with respect to the image is ``grad_image``).

    ``method`` "replay": every parameter's adjoint from one render (kernels/integrator.py: the backward variant):
    a path gathers its adjoints in registers as it is traced (kernels/adjoint.py), and only a path that meets more
    than ``ADJ_CAP`` parameters is traced again, as path replay backpropagation does (examples/bench_gradients.py);
    "forward": one forward-mode render per key (1x a render per key; the same derivatives, summed in another
    order); "auto" (default): forward for one key, replay for more."""
    spp = scene.spp if spp is None else spp
    seed = scene.sampler_seed if seed is None else seed
    w = np.asarray(grad_image, dtype=np.float64)
    if w.shape != (scene.height, scene.width, 3):
        raise RenderError(f"grad_image must be ({scene.height}, {scene.width}, 3), got {w.shape}")
    keys, method, params = _keys_and_method(scene, keys, method)
    opts = _with_sampler(opts, spp)
    if method == "forward":
        r = _renderer(scene, opts)
        try:
            out = {}
            for key in keys:
                _, g = _forward(r, key, params, spp, seed)
                out[key] = np.einsum("hwc,hwc->c", w, g.astype(np.float64))
            return out
        finally:
            r.close()
    r = _renderer(scene, opts, backward=True)
    try:
        r.set_adjoint(w / spp)
        r.render_passes(seed=seed, first_pass=0, count=spp)
        rgb, rad = r.adjoint()
    finally:
        r.close()
    return {key: _adjoint_of(params, key, rgb, rad) for key in keys}


def render_loss_gradient(scene, keys, loss_grad, spp: int | None = None, seed: int | None = None,
                         method: str = "auto", **opts) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """(image, key -> (3,) numpy): a render and the gradient of a loss of it, from one set of ``spp`` samples.

    ``loss_grad(image)`` returns dLoss/dimage, (H, W, 3); for the mean squared error against ``target``,
    ``lambda img: 2 * (img - target) / img.size``. The loss gradient needs the image and its derivative from
    independent samples (from the same ones it is biased: E[img grad] is not E[img] E[grad]); Mitsuba renders
    twice for that (``seed_grad``). Here the samples are split into two independent halves A and B, and each half's
    ``loss_grad`` weighs the other half's derivatives: 0.5 (sum w(A) dB + sum w(B) dA). For a loss quadratic in
    the image, such as the mean squared error, that is unbiased; the image is the mean of both halves. ``method``:
    "forward" (one forward-mode render per key), "replay" (one-pass adjoints: 1.5 renders for every key at once),
    "auto" (forward for one key). ``opts``: as ``Renderer``'s.
    """
    spp = scene.spp if spp is None else spp
    seed = scene.sampler_seed if seed is None else seed
    if not (isinstance(spp, (int, np.integer)) and spp >= 2):
        raise RenderError(f"spp must be an integer >= 2 (two halves), got {spp!r}")
    keys, method, params = _keys_and_method(scene, keys, method)
    # (seed, passes): two seeds, two independent sample sets (with Sobol' too: disjoint passes of one seed are not)
    halves = ((seed, spp // 2), (_other_seed(seed), spp - spp // 2))

    def weight(img: np.ndarray) -> np.ndarray:
        w = np.asarray(loss_grad(img), dtype=np.float64)
        if w.shape != (scene.height, scene.width, 3):
            raise RenderError(f"loss_grad must return ({scene.height}, {scene.width}, 3), got {w.shape}")
        return w

    opts = _with_sampler(opts, spp // 2)
    if method == "forward":
        r = _renderer(scene, opts)
        try:
            imgs, derivs = [], {key: [] for key in keys}
            for i, key in enumerate(keys):
                for half_seed, n in halves:
                    img, g = _forward(r, key, params, n, half_seed)
                    if i == 0:
                        imgs.append(img)
                    derivs[key].append(g.astype(np.float64))
        finally:
            r.close()
        w = [weight(img) for img in imgs]
        grads = {key: 0.5 * (np.einsum("hwc,hwc->c", w[0], d[1]) + np.einsum("hwc,hwc->c", w[1], d[0]))
                 for key, d in derivs.items()}
    else:
        r = _renderer(scene, opts, backward=True)
        try:
            (sa, na), (sb, nb) = halves
            r.set_adjoint(np.zeros((scene.height, scene.width, 3)))
            img_a = r.render_passes(seed=sa, count=na).mean
            w_a = weight(img_a)
            r.set_adjoint(w_a / nb)  # B's paths, weighed by A's loss gradient
            img_b = r.render_passes(seed=sb, count=nb).mean
            rgb, rad = r.adjoint()
            w_b = weight(img_b)
            r.set_adjoint(w_b / na)  # A's paths again, weighed by B's
            r.render_passes(seed=sa, count=na)
            rgb2, rad2 = r.adjoint()
        finally:
            r.close()
        imgs = [img_a, img_b]
        grads = {key: 0.5 * _adjoint_of(params, key, rgb + rgb2, rad + rad2) for key in keys}
    (_, na), (_, nb) = halves
    image = ((na * imgs[0].astype(np.float64) + nb * imgs[1]) / spp).astype(np.float32)
    return image, grads


# ---------------------------------------------------------------- the Warp-native form: wp.Tape


def _runtime():
    import warp as wp

    ctx = getattr(getattr(wp, "_src", None), "context", None) or getattr(wp, "context")
    ctx.init()
    return ctx.runtime


def render_wp(scene, params: dict, spp: int | None = None, seed: int | None = None, seed_grad: int | None = None,
              **opts):
    """The image as a ``wp.array`` of ``wp.vec3`` (H * W, row-major) rendered with the values of ``params``
    (key -> ``wp.array`` of one ``wp.vec3``, ``requires_grad=True``), for optimisation loops in Warp:

        with wp.Tape() as tape:
            img = pathtracer.gradients.render_wp(scene, {"red.reflectance.value": rho}, spp=4, seed=it)
            wp.launch(loss_kernel, dim=n, inputs=[img, target], outputs=[loss])
        tape.backward(loss)        # rho.grad now holds dLoss/drho

    Inside a tape, the render is recorded as one step whose backward pass is ``render_backward`` of the image's
    adjoint (``img.grad``), from independent samples (``seed_grad``, default derived from ``seed``, as Mitsuba's
    render does: the same samples would bias the loss gradient); its own kernels are not recorded.
    """
    import warp as wp

    spp = scene.spp if spp is None else spp
    seed = scene.sampler_seed if seed is None else seed
    seed_grad = _other_seed(seed) if seed_grad is None else seed_grad
    values = traverse(scene)
    for key, arr in params.items():
        values[key] = np.asarray(arr.numpy(), dtype=np.float64).reshape(-1)[:3]
    runtime = _runtime()
    tape, runtime.tape = runtime.tape, None  # our own launches are not the tape's: their adjoint is ours below
    try:
        from pathtracer.render import render

        img = render(scene, spp=spp, seed=seed, progress=False, light_tracing=False, **opts)
        device = next(iter(params.values())).device if params else "cpu"
        out = wp.array(img.reshape(-1, 3), dtype=wp.vec3, device=device, requires_grad=True)
    finally:
        runtime.tape = tape
    if tape is not None and params:
        keys = list(params)

        def backward():
            g = out.grad.numpy().reshape(scene.height, scene.width, 3).astype(np.float64)
            grads = render_backward(scene, keys, g, spp=spp, seed=seed_grad, **opts)
            for key in keys:
                a = params[key]
                a.grad.assign((a.grad.numpy().reshape(-1, 3) + grads[key]).astype(np.float32))

        tape.record_func(backward, [out, *params.values()])
    return out
