"""ID-PHD reduction: prune, greedy merge within each tag (3-D Mahalanobis distance with wrapped
headings), cap."""

from __future__ import annotations

import numpy as np

from ..gaussian import wrap_angle
from ..reducer import greedy_clusters

_WEIGHT_FLOOR = 1e-150


def reduce_tagged(
    weights: np.ndarray,
    means: np.ndarray,
    covs: np.ndarray,
    tags: np.ndarray,
    prune_threshold: float,
    merge_threshold: float,
    max_components: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Prune, merge within each tag (Vo & Ma greedy, 3-D gate, wrapped heading), cap.

    Component ``i`` joins heavier component ``j`` of the same tag when
    ``d^T P_i^-1 d <= merge_threshold`` with ``d = m_i - m_j`` (heading difference wrapped) and
    the candidate's 3x3 covariance ``P_i`` (Vo & Ma's choice). Clusters come from
    :func:`localization.reducer.greedy_clusters`; each is moment-matched about its leader's
    heading. The loop runs over the distinct tags (a few tens), never over components.
    Returns components grouped by tag.
    """
    keep = weights >= prune_threshold
    weights, means, covs, tags = weights[keep], means[keep], covs[keep], tags[keep]
    if weights.shape[0] > 1:
        order = np.argsort(tags, kind="stable")
        weights, means, covs, tags = weights[order], means[order], covs[order], tags[order]
        bounds = np.flatnonzero(np.diff(tags)) + 1
        parts = [
            _merge_block(weights[a:b], means[a:b], covs[a:b], merge_threshold)
            for a, b in zip(
                np.concatenate(([0], bounds)).tolist(),
                np.concatenate((bounds, [weights.shape[0]])).tolist(),
                strict=True,
            )
        ]
        counts = [part[0].shape[0] for part in parts]
        tags = np.repeat(tags[np.concatenate(([0], bounds))], counts)
        weights = np.concatenate([part[0] for part in parts])
        means = np.concatenate([part[1] for part in parts])
        covs = np.concatenate([part[2] for part in parts])
    if weights.shape[0] > max_components:
        top = np.sort(np.argpartition(-weights, max_components - 1)[:max_components])
        weights, means, covs, tags = weights[top], means[top], covs[top], tags[top]
    return weights, means, covs, tags


def _merge_block(
    weights: np.ndarray, means: np.ndarray, covs: np.ndarray, threshold: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Greedy merge of components that share one tag (see :func:`reduce_tagged`)."""
    n = weights.shape[0]
    if n < 2:
        return weights, means, covs
    diff = means[None, :, :] - means[:, None, :]  # [j, i] = m_i - m_j
    diff[..., 2] = wrap_angle(diff[..., 2])
    inv = np.linalg.inv(covs)  # candidate i's inverse, (N, 3, 3)
    q = np.einsum("jik,ikl,jil->ji", diff, inv, diff, optimize=False)
    close = q <= threshold
    np.fill_diagonal(close, True)
    labels = greedy_clusters(close, weights)
    leaders = np.flatnonzero(labels == np.arange(n))
    if leaders.shape[0] == n:
        return weights, means, covs
    member_of = labels == leaders[:, None]  # (L, N)
    # Guard: floored weights, so an all-zero cluster still has a defined mean and covariance.
    member = member_of * np.maximum(weights, _WEIGHT_FLOOR)
    total = member.sum(axis=1)
    d = diff[leaders]  # (L, N, 3): m_i - m_leader, heading wrapped
    mean_d = np.einsum("ln,lnk->lk", member, d) / total[:, None]
    dd = d - mean_d[:, None, :]
    spread = np.einsum("ln,lnk,lnm->lkm", member, dd, dd)
    new_covs = (np.einsum("ln,nkm->lkm", member, covs) + spread) / total[:, None, None]
    new_means = means[leaders] + mean_d
    new_means[:, 2] = wrap_angle(new_means[:, 2])
    return (
        member_of.astype(float) @ weights,
        new_means,
        0.5 * (new_covs + new_covs.transpose(0, 2, 1)),
    )


# ---------------------------------------------------------------------- the filter
