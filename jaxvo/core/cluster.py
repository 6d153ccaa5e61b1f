"""DBSCAN of a fixed number of motion hypotheses (thesis section 3.3, Algorithm 2), pure JAX.

Hypotheses are compared by the Jaccard distance of their inlier sets: two hypotheses that
describe the same rigid motion explain (nearly) the same grid points whatever their exact
parameters, while different motions explain disjoint sets. This is unit-free (no weighting of
radians against metres) and insensitive to how well a hypothesis was refined.
"""

from __future__ import annotations

import jax.numpy as jnp


def overlaps(inliers):
    """(H, H) float32 ``|A n B|`` of boolean sets ``inliers`` (H, n); the diagonal holds the
    set sizes. The one product both the Jaccard distance and the spatial stage's member
    choice need."""
    f = inliers.astype(jnp.float32)
    return f @ f.T


def jaccard_distance(inliers, inter=None):
    """Pairwise Jaccard distance ``1 - |A n B| / |A u B|`` of boolean sets.

    Args:
      inliers: (H, n) bool, one inlier set per hypothesis.
      inter: optional :func:`overlaps` of ``inliers``, when already computed.

    Returns:
      (H, H) float32 distances in [0, 1]; 1 between two empty sets.
    """
    inter = overlaps(inliers) if inter is None else inter
    size = jnp.diagonal(inter)
    union = size[:, None] + size[None, :] - inter
    return 1.0 - inter / jnp.maximum(union, 1.0)


def dbscan(dist, valid, eps, min_samples):
    """DBSCAN on a precomputed distance matrix with a fixed number of items.

    Follows scikit-learn's ``DBSCAN(metric="precomputed")`` exactly: neighbours are items at
    distance ``<= eps`` (the item itself included), core items have at least ``min_samples``
    neighbours, clusters are the connected components of core items, and a border item joins
    the cluster that scikit-learn's scan would reach first, i.e. the adjacent cluster whose
    lowest-index core item is lowest. Clusters are numbered 0, 1, ... in order of their
    lowest-index core item, as scikit-learn numbers them.

    Connected components come from boolean reachability squared ``ceil(log2 H)`` times
    (fixed trip count; ``H`` is small: the hypothesis count).

    Args:
      dist: (H, H) symmetric distances.
      valid: (H,) bool; invalid items take no part and are labelled -1.
      eps: () neighbourhood radius (may be traced).
      min_samples: () core threshold, neighbours including the item itself (may be traced).

    Returns:
      labels: (H,) int32 cluster index, -1 for noise or invalid items.
      num_clusters: () int32.
    """
    h = dist.shape[0]
    idx = jnp.arange(h)
    adj = (dist <= eps) & valid[:, None] & valid[None, :]
    core = valid & (jnp.sum(adj, axis=1) >= min_samples)
    reach = adj & core[:, None] & core[None, :]
    reach = reach | jnp.eye(h, dtype=bool)
    for _ in range(max(1, (h - 1).bit_length())):
        rf = reach.astype(jnp.float32)
        reach = (rf @ rf) > 0.5
    # Root of a core item: the lowest index of its component.
    root = jnp.min(jnp.where(reach, idx[None, :], h), axis=1)
    root = jnp.where(core, root, h)
    # Border items: lowest root among adjacent core items.
    border_root = jnp.min(jnp.where(adj & core[None, :], root[None, :], h), axis=1)
    root = jnp.where(core, root, jnp.where(valid, border_root, h))
    is_root = core & (root == idx)
    number = jnp.cumsum(is_root.astype(jnp.int32)) - 1
    labels = jnp.where(root < h, number[jnp.minimum(root, h - 1)], -1)
    return labels.astype(jnp.int32), jnp.sum(is_root).astype(jnp.int32)
