"""A bounding volume hierarchy over boxes, built with numpy and Warp for ``kernels/triangle.py``'s nearest-first
traversal.

Why our own: Warp 1.19's ``wp.Bvh`` ray query visits a node's two children in a fixed order, so a closest-hit query
keeps descending into far subtrees until a hit shrinks its limit; on the mirror teapot that traversal was 60% of the
render time. Here the traversal tests both children and descends into the nearer one first.

Every inner node cuts its range of primitives, along the axis where their centres spread most, where the surface
area heuristic counted in 4-primitive leaf blocks is lowest (the sweeps in a CPU Warp kernel, one thread per range;
the three sorted orders kept by stable partitions rather than sorted again), or at the middle at deep levels: the
bunny (70k triangles) builds in about 0.1 s. Counting blocks rather than primitives, at every range rather than
from 16 primitives on, gave the traversal fuller leaves.
``collapse_wide`` turns the binary tree into the 4-wide one the kernels traverse (each node takes its grandchildren).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

LEAF_SIZE = 4  # at most this many primitives per leaf
SAH_LEVELS = 32  # below this depth, medians only: the tree stays shallower than the traversal's 64-entry stack


@dataclass
class BoxTree:
    """Node arrays; node 0 is the root, an inner node's children are ``start`` and ``start + 1``."""

    lower: np.ndarray  # (nodes, 3) float32
    upper: np.ndarray  # (nodes, 3) float32
    start: np.ndarray  # (nodes,) int32: a leaf's first entry in ``prims``; an inner node's first child
    count: np.ndarray  # (nodes,) int32: a leaf's primitive count, 0 for inner nodes
    prims: np.ndarray  # (n,) int32: primitive indices, leaf by leaf
    depth: int  # the number of levels


def _ranges(starts: np.ndarray, sizes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(element positions, segment of each) for the concatenated ranges [starts[k], starts[k] + sizes[k])."""
    seg = np.repeat(np.arange(len(starts)), sizes)
    offsets = np.cumsum(sizes) - sizes
    return starts[seg] + np.arange(int(sizes.sum())) - offsets[seg], seg


MORTON_MIN = 200_000  # from this many boxes on, build_tree uses the Morton (linear) builder
MORTON_BITS = 21  # per axis: 63-bit codes
MORTON_MEDIAN_LEVELS = 40  # below this depth, medians: the tree stays shallow even where codes cluster


def column_min(a: np.ndarray) -> np.ndarray:
    """``a.min(axis=0)`` of an (n, k) array as float64, column by column: numpy's axis-0 reduction of a
    C-ordered array runs 15x slower (0.18 s against 0.012 s on 5M points)."""
    return np.array([a[:, j].min() for j in range(a.shape[1])], dtype=np.float64)


def column_max(a: np.ndarray) -> np.ndarray:
    """``a.max(axis=0)`` as float64, column by column (see ``column_min``)."""
    return np.array([a[:, j].max() for j in range(a.shape[1])], dtype=np.float64)


def morton_codes(lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
    """63-bit Morton codes of the boxes' centres, quantised over the centres' bounding box (``kernels/bvh_build.py``
    on the CPU; 25x faster than numpy on 5M boxes)."""
    import warp as wp

    from kernels.bvh_build import morton_codes as kernel
    from pathtracer.warp_setup import init_warp

    init_warp()
    lo_c = 0.5 * (column_min(lower) + column_min(upper))  # bounds of the centres, conservatively
    hi_c = 0.5 * (column_max(lower) + column_max(upper))
    inv = 1.0 / np.maximum(hi_c - lo_c, 1e-300)
    codes = wp.empty(len(lower), dtype=wp.uint64, device="cpu")  # the kernel writes every code
    wp.launch(kernel, dim=len(lower), device="cpu",
              inputs=[wp.array(lower, dtype=wp.vec3, device="cpu"), wp.array(upper, dtype=wp.vec3, device="cpu"),
                      wp.vec3d(*lo_c), wp.vec3d(*inv)], outputs=[codes])
    return codes.numpy()


def _highest_bit(x: np.ndarray) -> np.ndarray:
    """floor(log2(x)) of uint64 x > 0, exact (the float estimate corrected by a shift test)."""
    b = np.floor(np.log2(x.astype(np.float64))).astype(np.uint64)
    too_high = (x >> b) == 0
    b[too_high] -= np.uint64(1)
    low = (x >> b) > 1
    b[low] += np.uint64(1)
    return b


def _split_levels(n: int, leaf_size: int, choose_cut) -> tuple[list, int]:
    """Plan a binary tree over n primitives level by level: every range of more than ``leaf_size`` is cut in two
    at ``choose_cut(starts, sizes, level)`` (one cut per range, for all of a level's ranges at once; it may reorder
    the ranges' primitives first). Returns, per level, (node ids, range starts, sizes, first child of each inner
    node or -1), and the node count: what ``_bottom_up`` turns into the node arrays."""
    levels = []
    ids, starts, sizes = np.array([0]), np.array([0]), np.array([n])
    next_id = 1
    while len(ids):
        inner = sizes > leaf_size
        children = np.full(len(ids), -1)
        children[inner] = next_id + 2 * np.arange(int(inner.sum()))
        levels.append((ids, starts, sizes, children))
        if not inner.any():
            break
        ids_in, starts, sizes = children[inner], starts[inner], sizes[inner]
        next_id += 2 * len(ids_in)
        cut = choose_cut(starts, sizes, len(levels))
        ids = np.stack([ids_in, ids_in + 1], axis=1).reshape(-1)
        starts, sizes = (np.stack([starts, starts + cut], axis=1).reshape(-1),
                         np.stack([cut, sizes - cut], axis=1).reshape(-1))
    return levels, next_id


def build_morton_tree(lower: np.ndarray, upper: np.ndarray, leaf_size: int = LEAF_SIZE) -> BoxTree:
    """A linear BVH (Karras 2012, built level by level): the boxes sorted once by the Morton code of their centres,
    every range cut where its codes' highest differing bit changes (found by a binary search in the sorted
    codes), at the middle where all its codes are equal or below MORTON_MEDIAN_LEVELS. No sweep and no per-level
    sort, so millions of boxes build in seconds; the trees trace somewhat slower than the SAH builder's."""
    lower = np.asarray(lower, dtype=np.float32).reshape(-1, 3)
    upper = np.asarray(upper, dtype=np.float32).reshape(-1, 3)
    n = len(lower)
    if n == 0:
        raise ValueError("a box tree needs at least one box")
    codes = morton_codes(np.ascontiguousarray(lower), np.ascontiguousarray(upper))
    perm = np.argsort(codes, kind="stable")
    codes = codes[perm]

    def choose_cut(starts, sizes, level):
        first, last = codes[starts], codes[starts + sizes - 1]
        cut = sizes // 2
        differ = first != last
        if level <= MORTON_MEDIAN_LEVELS and differ.any():
            f = first[differ]
            bit = _highest_bit(f ^ last[differ])
            threshold = ((f >> bit) | np.uint64(1)) << bit
            cut[differ] = np.searchsorted(codes, threshold, side="left") - starts[differ]
        return cut

    levels, next_id = _split_levels(n, leaf_size, choose_cut)
    return _bottom_up(levels, next_id, perm, lower, upper)


def build_tree(lower: np.ndarray, upper: np.ndarray) -> BoxTree:
    """The SAH builder up to MORTON_MIN boxes, the Morton builder beyond (where the SAH one takes minutes)."""
    if len(lower) >= MORTON_MIN:
        return build_morton_tree(lower, upper)
    return build_box_tree(lower, upper)


def build_box_tree(lower: np.ndarray, upper: np.ndarray, leaf_size: int = LEAF_SIZE) -> BoxTree:
    """Tree over the boxes [lower[i], upper[i]] (float32, already padded as the caller needs).

    Level by level, every range of more than ``leaf_size`` boxes is cut along the axis where its box centres spread
    most, where the surface area heuristic counted in leaf blocks (``kernels/bvh_build.py`` sah_sweep, one CPU
    thread per range) is lowest, or at the middle below SAH_LEVELS. The boxes are sorted along each axis once; a
    cut partitions all three orders stably, so every range stays sorted along every axis without sorting again.
    (Choosing the axis by the lowest cost of all three sweeps gave the bunny's random rays nothing and slowed the
    teapot scene's camera rays by a fifth: its camera is inside the box, where the heuristic's rays from outside
    mislead.)"""
    lower = np.asarray(lower, dtype=np.float32).reshape(-1, 3)
    upper = np.asarray(upper, dtype=np.float32).reshape(-1, 3)
    n = len(lower)
    if n == 0:
        raise ValueError("a box tree needs at least one box")
    import warp as wp

    from kernels.bvh_build import sah_sweep
    from pathtracer.warp_setup import init_warp

    init_warp()
    centre = 0.5 * (lower.astype(np.float64) + upper)
    order = np.stack([np.argsort(centre[:, a], kind="stable") for a in range(3)]).astype(np.int32)  # (3, n)
    is_left = np.zeros(n, dtype=bool)
    lower_wp = wp.array(lower, dtype=wp.vec3, device="cpu")
    upper_wp = wp.array(upper, dtype=wp.vec3, device="cpu")
    order_wp = wp.array(order.reshape(-1), dtype=wp.int32, device="cpu", copy=False)  # a view: sees every partition
    scratch = wp.empty(3 * n, dtype=wp.float64, device="cpu")
    axes = np.arange(3)[:, None]

    def choose_cut(starts, sizes, level):
        pos, seg = _ranges(starts, sizes)
        rank = pos - starts[seg]
        ends = starts + sizes - 1
        axis = np.argmax(centre[order[:, ends], axes] - centre[order[:, starts], axes], axis=0)  # widest centres
        if level <= SAH_LEVELS:
            cost_wp = wp.empty(len(sizes), dtype=wp.float64, device="cpu")
            cut_wp = wp.empty(len(sizes), dtype=wp.int32, device="cpu")
            wp.launch(sah_sweep, dim=len(sizes), device="cpu",
                      inputs=[order_wp, lower_wp, upper_wp, wp.array((axis * n + starts).astype(np.int32),
                                                                     dtype=wp.int32, device="cpu"),
                              wp.array(sizes.astype(np.int32), dtype=wp.int32, device="cpu"), leaf_size, scratch],
                      outputs=[cost_wp, cut_wp])
            cut = cut_wp.numpy().astype(np.int64)
        else:
            cut = sizes // 2
        chosen = order[axis[seg], pos]
        is_left[chosen] = rank < cut[seg]
        offsets = np.cumsum(sizes) - sizes
        for a in range(3):  # stable partition of every range, left boxes first, in all three orders
            ids = order[a, pos]
            left = is_left[ids]
            before_l = np.cumsum(left) - left  # left boxes before each position
            before_r = np.arange(len(ids)) - before_l
            lrank = before_l - before_l[offsets][seg]
            rrank = before_r - before_r[offsets][seg]
            order[a, starts[seg] + np.where(left, lrank, cut[seg] + rrank)] = ids
        return cut

    levels, next_id = _split_levels(n, leaf_size, choose_cut)
    return _bottom_up(levels, next_id, order[0].copy(), lower, upper)


def _bottom_up(levels, nodes: int, perm: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> BoxTree:
    """The node arrays from the planned splits (per level: node ids, range starts and sizes, first children):
    leaf boxes from their primitives, inner boxes from their children, deepest level first.

    The leaves of all levels together tile the primitives' positions, so one ``reduceat`` per axis over the
    permuted boxes gives every leaf's box (per axis on contiguous columns: numpy's axis-0 reductions of (n, 3)
    arrays run many times slower)."""
    lo = np.full((nodes, 3), np.inf, dtype=np.float32)
    hi = np.full((nodes, 3), -np.inf, dtype=np.float32)
    start = np.zeros(nodes, dtype=np.int32)
    count = np.zeros(nodes, dtype=np.int32)
    leaf_of = [(ids[ch < 0], st[ch < 0], sz[ch < 0]) for ids, st, sz, ch in levels]
    li, ls, lz = (np.concatenate([lv[k] for lv in leaf_of]) for k in range(3))
    order = np.argsort(ls)
    li, ls, lz = li[order], ls[order], lz[order]
    for axis in range(3):
        lo[li, axis] = np.minimum.reduceat(np.ascontiguousarray(lower[perm, axis]), ls)
        hi[li, axis] = np.maximum.reduceat(np.ascontiguousarray(upper[perm, axis]), ls)
    start[li] = ls
    count[li] = lz
    for lv_ids, _, _, lv_children in reversed(levels):  # deepest first: children before parents
        inner = lv_children >= 0
        ii, cc = lv_ids[inner], lv_children[inner]
        if len(ii):
            lo[ii] = np.minimum(lo[cc], lo[cc + 1])
            hi[ii] = np.maximum(hi[cc], hi[cc + 1])
            start[ii] = cc
    return BoxTree(lo, hi, start, count, perm.astype(np.int32), len(levels))


WIDTH = 4  # children per node of the wide tree
EMPTY_SLOT = -1  # child reference of an unused slot (its box is empty: +inf lower, -inf upper)


def leaf_ref(block: np.ndarray) -> np.ndarray:
    """Child reference of leaf block ``block``: -2 - block; inner nodes are referenced by their index (>= 0)."""
    return -2 - np.asarray(block, np.int64)


@dataclass
class WideTree:
    """A 4-wide tree in structure-of-arrays form, for ``kernels/triangle.py``'s vectorised box tests.

    ``boxes[6 n + 2 a]`` holds the lower bounds of node n's four children along axis a, ``boxes[6 n + 2 a + 1]`` the
    upper bounds (so a ray picks its near and far planes per axis by its direction's sign). ``child[n]`` holds
    the four child references: an inner node's index (>= 0), a leaf block (``leaf_ref``), or ``EMPTY_SLOT``.
    Leaf block k holds the primitives ``prims[leaf_start[k]:leaf_start[k] + leaf_count[k]]`` (at most 4).
    ``root`` is a reference too (a leaf when n <= LEAF_SIZE).
    """

    boxes: np.ndarray  # (6 nodes, 4) float32
    child: np.ndarray  # (nodes, 4) int32
    prims: np.ndarray  # (n,) int32, leaf by leaf (as the binary tree's)
    leaf_start: np.ndarray  # (leaves,) int64: first entry of each leaf block in prims
    leaf_count: np.ndarray  # (leaves,) int64
    root: int
    depth: int  # levels of inner nodes
    stack_bound: int  # the most entries a closest-hit traversal can hold on its stack (siblings along a path)


def collapse_wide(tree: BoxTree, width: int = WIDTH) -> WideTree:
    """Every wide node takes the binary descendants of its binary node log2(width) levels down (a leaf stands for
    itself): 2 to ``width`` children.

    Level by level, vectorised. The boxes are the binary nodes' own (already padded) float32 boxes, so the wide
    traversal tests exactly the boxes the binary one did, only ``width`` at once."""
    is_leaf = tree.count > 0
    leaf_nodes = np.flatnonzero(is_leaf)
    leaf_nodes = leaf_nodes[np.argsort(tree.start[leaf_nodes])]  # blocks in prims order
    block_of = np.full(len(is_leaf), -1, dtype=np.int64)
    block_of[leaf_nodes] = np.arange(len(leaf_nodes))
    leaf_start = tree.start[leaf_nodes].astype(np.int64)
    leaf_count = tree.count[leaf_nodes].astype(np.int64)
    lo4, hi4, ch4 = [], [], []
    if is_leaf[0]:
        return WideTree(np.zeros((0, width), np.float32), np.zeros((0, width), np.int32), tree.prims, leaf_start,
                        leaf_count, int(leaf_ref(0)), 0, 0)
    level = np.array([0])  # binary ids of this level's wide nodes
    bound = np.array([0])  # stack entries their traversal may already hold
    next_id = 1
    depth, stack_bound = 0, 0
    while len(level):
        depth += 1
        slots = level[:, None]
        while slots.shape[1] < width:  # replace every inner binary node by its two children
            used = slots >= 0
            expand = used & ~is_leaf[np.maximum(slots, 0)]
            first = np.where(expand, tree.start[np.maximum(slots, 0)], slots)
            second = np.where(expand, first + 1, -1)
            slots = np.stack([first, second], axis=2).reshape(len(level), -1)
        used = slots >= 0
        b = np.where(used, slots, 0)
        lo = np.where(used[..., None], tree.lower[b], np.inf).astype(np.float32)  # (k, width, 3)
        hi = np.where(used[..., None], tree.upper[b], -np.inf).astype(np.float32)
        child_inner = used & ~is_leaf[b]
        ids = np.full(slots.shape, EMPTY_SLOT, dtype=np.int64)
        new = np.flatnonzero(child_inner.reshape(-1))
        ids.reshape(-1)[new] = next_id + np.arange(len(new))
        next_id += len(new)
        leaves = used & is_leaf[b]
        ids[leaves] = leaf_ref(block_of[b[leaves]])
        lo4.append(lo)
        hi4.append(hi)
        ch4.append(ids)
        # siblings pushed on the way down: at most (children - 1) per node on the path
        here = bound + used.sum(axis=1) - 1
        stack_bound = max(stack_bound, int(here.max()))
        level = b.reshape(-1)[new]
        bound = np.repeat(here, child_inner.sum(axis=1))
    lo = np.concatenate(lo4)
    hi = np.concatenate(hi4)
    boxes = np.empty((len(lo), 3, 2, width), dtype=np.float32)
    boxes[:, :, 0, :] = lo.transpose(0, 2, 1)
    boxes[:, :, 1, :] = hi.transpose(0, 2, 1)
    child = np.concatenate(ch4).astype(np.int32)
    return WideTree(boxes.reshape(-1, width), child, tree.prims, leaf_start, leaf_count, root=0, depth=depth,
                    stack_bound=stack_bound)

def leaf_lanes(wide: WideTree) -> np.ndarray:
    """(leaves, 4) primitive index of each leaf block's lanes, -1 where a block holds fewer than four."""
    lanes = np.arange(WIDTH)
    pos = wide.leaf_start[:, None] + lanes[None, :]
    used = lanes[None, :] < wide.leaf_count[:, None]
    return np.where(used, wide.prims[np.where(used, pos, 0)], -1)
