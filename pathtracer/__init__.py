"""A physically based Monte Carlo path tracer whose hot loops are NVIDIA Warp kernels.

    import pathtracer
    scene = pathtracer.load_file("scenes/cornell_box.xml", spp=64)
    image = pathtracer.render(scene)              # linear radiance, float32 (H, W, 3)
    pathtracer.write_image("cornell.exr", image)
"""

from pathtracer.errors import ImageIOError, PathtracerError, RenderError, SceneError
from pathtracer.gradients import render_backward, render_forward, render_loss_gradient, traverse
from pathtracer.imageio import read_image, read_layers, write_image
from pathtracer.loader import load_dict, load_file
from pathtracer.render import PassSum, Renderer, render
from pathtracer.scene import Camera, Integrator, Material, RectLight, Scene, Sphere, TriangleMesh

__version__ = "0.1.0"

__all__ = [
    "Camera", "ImageIOError", "Integrator", "Material", "PassSum", "PathtracerError", "RectLight",
    "RenderError", "Renderer", "Scene", "SceneError", "Sphere", "TriangleMesh", "load_dict", "load_file",
    "read_image", "read_layers", "render", "render_backward", "render_forward", "render_loss_gradient", "traverse",
    "write_image",
]

