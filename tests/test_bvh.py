"""pathtracer/bvh.py: the box tree the triangle traversal (kernels/triangle.py) walks.

The 4-wide tree (collapse_wide) is checked the same way. The traversal itself is tested through the integrator's probes (test_kernels: nearest hits against float64
Moller-Trumbore; test_hard_cases: watertightness on the teapot, an icosphere and the bunny)."""

import numpy as np
import pytest

from kernels.triangle import STACK_SIZE, STACK_SLACK
from pathtracer.bvh import _highest_bit, build_box_tree, build_morton_tree, collapse_wide, leaf_lanes


def walk(tree, lower, upper):
    """Every node reachable from the root exactly once, every box the union of what it holds; returns the depth."""
    seen = np.zeros(len(tree.count), dtype=int)
    stack = [(0, 1)]
    deepest = 0
    while stack:
        i, depth = stack.pop()
        seen[i] += 1
        deepest = max(deepest, depth)
        if tree.count[i]:
            p = tree.prims[tree.start[i]:tree.start[i] + tree.count[i]]
            assert np.array_equal(tree.lower[i], lower[p].min(axis=0))
            assert np.array_equal(tree.upper[i], upper[p].max(axis=0))
        else:
            a = tree.start[i]
            assert a > i  # children come after their parent: no cycles
            assert np.array_equal(tree.lower[i], np.minimum(tree.lower[a], tree.lower[a + 1]))
            assert np.array_equal(tree.upper[i], np.maximum(tree.upper[a], tree.upper[a + 1]))
            stack += [(a, depth + 1), (a + 1, depth + 1)]
    assert (seen == 1).all()
    return deepest


def boxes(kind, n, rng):
    if kind == "uniform":
        c = rng.random((n, 3))
    elif kind == "identical":  # no axis to split along: the median must still split
        c = np.zeros((n, 3))
    elif kind == "geometric":  # exponentially spaced along a line: SAH would peel one box at a time
        c = np.stack([2.0 ** -np.arange(n, dtype=np.float64) * 1e3, np.zeros(n), np.zeros(n)], axis=1)
    else:  # a thin shell, like a mesh's surface
        v = rng.normal(size=(n, 3))
        c = v / np.linalg.norm(v, axis=1, keepdims=True)
    lo = (c - 1e-3).astype(np.float32)
    return lo, (c + 1e-3).astype(np.float32)


BUILDERS = {"sah": build_box_tree, "morton": build_morton_tree}


@pytest.mark.parametrize("builder", sorted(BUILDERS))
@pytest.mark.parametrize("kind", ["uniform", "identical", "geometric", "shell"])
@pytest.mark.parametrize("n", [1, 2, 4, 5, 17, 1000, 20000])
def test_tree_holds_every_box_once_with_tight_bounds_and_fits_the_stack(kind, n, builder):
    lower, upper = boxes(kind, n, np.random.default_rng(n))
    tree = BUILDERS[builder](lower, upper)
    assert np.array_equal(np.sort(tree.prims), np.arange(n))
    assert tree.count.sum() == n and tree.count.max() <= 4
    depth = walk(tree, lower, upper)
    assert depth == tree.depth
    # a closest-hit traversal pushes at most one node per level: the depth must stay below the stack size
    assert depth < STACK_SIZE


def test_tree_splits_where_the_area_is_smallest():
    """Two clusters of very different size: SAH cuts between them (a median cut would split the big cluster)."""
    rng = np.random.default_rng(1)
    big = rng.random((30, 3)) * 10.0
    small = 100.0 + rng.random((200, 3)) * 0.01
    c = np.concatenate([big, small])
    tree = build_box_tree((c - 1e-3).astype(np.float32), (c + 1e-3).astype(np.float32))
    a = tree.start[0]
    sizes = sorted(int(np.sum(tree.count[_subtree(tree, k)])) for k in (a, a + 1))
    assert sizes == [30, 200]


def _subtree(tree, root):
    out, stack = [], [root]
    while stack:
        i = stack.pop()
        out.append(i)
        if not tree.count[i]:
            stack += [tree.start[i], tree.start[i] + 1]
    return np.array(out)


def test_empty_input_is_an_error():
    with pytest.raises(ValueError):
        build_box_tree(np.zeros((0, 3)), np.zeros((0, 3)))


def walk_wide(wide, lower, upper):
    """Every leaf block reached once, every slot's box the union of what its subtree holds, empty slots empty;
    returns (primitives reached, the largest stack a closest-hit traversal can hold)."""
    reached = []
    deepest_stack = 0

    def visit(ref, pushed):
        nonlocal deepest_stack
        deepest_stack = max(deepest_stack, pushed)
        if ref <= -2:
            k = -2 - ref
            p = wide.prims[wide.leaf_start[k]:wide.leaf_start[k] + wide.leaf_count[k]]
            assert 1 <= len(p) <= 4
            reached.extend(p.tolist())
            return lower[p].min(axis=0), upper[p].max(axis=0)
        box = wide.boxes[6 * ref:6 * ref + 6]  # rows: lower x, upper x, lower y, upper y, lower z, upper z
        kids = wide.child[ref]
        used = kids != -1
        assert used.sum() >= 2
        lo_all, hi_all = np.full(3, np.inf, np.float32), np.full(3, -np.inf, np.float32)
        for k in range(4):
            if not used[k]:
                assert (box[0::2, k] == np.inf).all() and (box[1::2, k] == -np.inf).all()
                continue
            lo, hi = visit(int(kids[k]), pushed + int(used.sum()) - 1)
            assert np.array_equal(box[0::2, k], lo) and np.array_equal(box[1::2, k], hi)
            lo_all, hi_all = np.minimum(lo_all, lo), np.maximum(hi_all, hi)
        return lo_all, hi_all

    visit(wide.root, 0)
    return np.array(reached), deepest_stack


@pytest.mark.parametrize("builder", sorted(BUILDERS))
@pytest.mark.parametrize("kind", ["uniform", "identical", "geometric", "shell"])
@pytest.mark.parametrize("n", [1, 4, 5, 17, 1000, 20000])
def test_wide_tree_holds_every_box_once_with_exact_bounds_and_a_true_stack_bound(kind, n, builder):
    lower, upper = boxes(kind, n, np.random.default_rng(n))
    wide = collapse_wide(BUILDERS[builder](lower, upper))
    reached, stack = walk_wide(wide, lower, upper)
    assert np.array_equal(np.sort(reached), np.arange(n))
    assert stack == wide.stack_bound and wide.stack_bound + STACK_SLACK < STACK_SIZE
    lanes = leaf_lanes(wide)
    assert np.array_equal(np.sort(lanes[lanes >= 0]), np.arange(n))


def test_highest_bit_is_exact_where_float64_rounds():
    x = np.array([1, 2, 3, 2**53 + 1, 2**60 - 1, 2**62, 2**63 - 1, 2**64 - 1], dtype=np.uint64)
    assert _highest_bit(x).tolist() == [int(v).bit_length() - 1 for v in x.tolist()]


def test_morton_tree_cuts_between_clusters():
    """Two far-apart clusters: the root's cut separates them (their codes differ in the top bit)."""
    rng = np.random.default_rng(2)
    c = np.concatenate([rng.random((300, 3)), 100.0 + rng.random((500, 3))])
    tree = build_morton_tree((c - 1e-3).astype(np.float32), (c + 1e-3).astype(np.float32))
    a = tree.start[0]
    sizes = sorted(int(np.sum(tree.count[_subtree(tree, k)])) for k in (a, a + 1))
    assert sizes == [300, 500]


def test_sah_sweep_finds_the_cheapest_cut_in_leaf_blocks():
    """kernels/bvh_build.py sah_sweep against every cut of each range, costed in numpy: area(left) x blocks(left) +
    area(right) x blocks(right), blocks = ceil(boxes / 4); ties may go to any of the cheapest cuts."""
    import warp as wp

    from kernels.bvh_build import sah_sweep
    from pathtracer.warp_setup import init_warp

    init_warp()
    rng = np.random.default_rng(3)
    sizes = np.array([2, 3, 5, 8, 9, 17, 40, 200])
    starts = np.cumsum(sizes) - sizes
    n = int(sizes.sum())
    c = rng.normal(size=(n, 3)) * np.array([3.0, 1.0, 0.3])
    ext = rng.uniform(0.01, 0.5, (n, 3))
    lower, upper = (c - ext).astype(np.float32), (c + ext).astype(np.float32)
    order = np.concatenate([s + np.argsort(c[s:s + m, 0]) for s, m in zip(starts, sizes)]).astype(np.int32)
    cost = wp.zeros(len(sizes), dtype=wp.float64, device="cpu")
    cut = wp.zeros(len(sizes), dtype=wp.int32, device="cpu")
    wp.launch(sah_sweep, dim=len(sizes), device="cpu",
              inputs=[wp.array(order, dtype=wp.int32, device="cpu"), wp.array(lower, dtype=wp.vec3, device="cpu"),
                      wp.array(upper, dtype=wp.vec3, device="cpu"), wp.array(starts.astype(np.int32), dtype=wp.int32,
                                                                               device="cpu"),
                      wp.array(sizes.astype(np.int32), dtype=wp.int32, device="cpu"), 4,
                      wp.zeros(n, dtype=wp.float64, device="cpu")], outputs=[cost, cut])
    cost, cut = cost.numpy(), cut.numpy()

    def area(ids):
        e = upper[ids].astype(np.float64).max(axis=0) - lower[ids].astype(np.float64).min(axis=0)
        return e[0] * e[1] + e[1] * e[2] + e[2] * e[0]

    for j, (s, m) in enumerate(zip(starts, sizes)):
        ids = order[s:s + m]
        costs = np.array([area(ids[:k]) * np.ceil(k / 4) + area(ids[k:]) * np.ceil((m - k) / 4) for k in range(1, m)])
        assert 1 <= cut[j] < m
        assert costs[cut[j] - 1] <= costs.min() * (1 + 1e-9)
        assert abs(cost[j] - costs.min()) <= 1e-6 * costs.min()
