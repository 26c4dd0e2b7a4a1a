"""The inverse-albedo optimisation of examples/inverse_albedo.py with PyTorch's autograd and Adam: the render is a
``torch.autograd.Function`` whose tensors cross into Warp by ``wp.from_torch`` / ``wp.to_torch`` and whose backward
pass is the ``wp.Tape`` that ``pathtracer.gradients.render_wp`` records itself on.

    pip install torch  # (an optional extra: nothing else in this project needs it)
    python examples/torch_albedo.py
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
KEY = "red.reflectance.value"


def main() -> None:
    import torch
    import warp as wp

    import pathtracer
    from pathtracer.gradients import render_wp

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--size", type=int, default=128)
    ap.add_argument("--iterations", type=int, default=50)
    ap.add_argument("--spp", type=int, default=4)
    ap.add_argument("--lr", type=float, default=0.05)
    a = ap.parse_args()

    scene = pathtracer.load_file(str(ROOT / "scenes" / "cornell_box.xml"), width=a.size, height=a.size)
    truth = pathtracer.traverse(scene)[KEY].copy()
    target = torch.from_numpy(pathtracer.render(scene, spp=512, seed=10**6, progress=False, light_tracing=False))

    class Render(torch.autograd.Function):
        @staticmethod
        def forward(ctx, rho: torch.Tensor, seed: int) -> torch.Tensor:
            rho_wp = wp.from_torch(rho.detach().reshape(1, 3).contiguous(), dtype=wp.vec3, requires_grad=True)
            tape = wp.Tape()
            with tape:
                img = render_wp(scene, {KEY: rho_wp}, spp=a.spp, seed=seed)
            ctx.tape, ctx.img, ctx.rho_wp = tape, img, rho_wp
            return wp.to_torch(img).reshape(a.size, a.size, 3).clone()

        @staticmethod
        def backward(ctx, grad: torch.Tensor):
            ctx.img.grad = wp.from_torch(grad.reshape(-1, 3).contiguous().float(), dtype=wp.vec3)
            ctx.tape.backward(grads={ctx.img: ctx.img.grad})
            return wp.to_torch(ctx.rho_wp.grad).reshape(3).clone(), None

    rho = torch.tensor([0.01, 0.2, 0.9], requires_grad=True)
    opt = torch.optim.Adam([rho], lr=a.lr)
    for it in range(a.iterations):
        opt.zero_grad()
        loss = torch.mean((Render.apply(rho, it) - target) ** 2)
        loss.backward()
        opt.step()
        with torch.no_grad():
            rho.clamp_(0.0, 1.0)
        if it % 10 == 9 or it == a.iterations - 1:
            err = float(np.sum((rho.detach().numpy() - truth) ** 2))
            print(f"iteration {it + 1}: loss {loss.item():.4f}, red wall {np.round(rho.detach().numpy(), 3)}, "
                  f"squared parameter error {err:.2e}", flush=True)


if __name__ == "__main__":
    main()
