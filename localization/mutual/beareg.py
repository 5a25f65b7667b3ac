"""P-MultiBeaReg: bearing-only multiple registration (Stegagno 2012 chapter 10, Algorithm 2).

Each robot's feature set is a set of anonymous **bearings** ``B_a`` (its own frame). Three robots
``a, b, c`` that see each other form a triangle: in ``B_a`` the bearings to ``b`` and ``c``
differ by the interior angle at ``a``, and the three interior angles sum to ``pi``. With signed
differences (counter-clockwise positive) ``s_a = beta_ac - beta_ab``, ``s_b = beta_ba - beta_bc``,
``s_c = beta_cb - beta_ca``, a counter-clockwise triangle has all three in ``(0, pi)`` summing to
``pi`` (clockwise: all negative, summing to ``-pi``). Each triple of feature pairs passing this
test within ``tol_rad`` is a candidate triangle, defined up to scale; it carries the robots'
identities at its vertices, hence for the observer ``i = a`` the **bearing-orientation**
``xi_b = (beta_ab, theta_b)`` of ``b``, with ``theta_b = beta_ab + pi - beta_ba`` (the ray from
``b`` back to ``a``), and the same for ``c``.

Triangles are rated by their **3-intersections**: placed at unit scale (law of sines for the
third side), the remaining rays of ``a``, ``b`` and ``c`` that meet in one point (a fourth robot,
or a decoy, seen by all three). The triangles containing the observer with the best rating form
the partial solutions; mutually consistent ones (no robot on two features of one set, no feature
for two robots) are merged into complete solutions (maximal consistent sets), each giving every
teammate it contains one ``xi``. The particle filter's update uses ``xi`` (eq. 19:
``p(xi_hat | x) = N(bearing(x) - beta_hat; s_b) N(theta - theta_hat; s_t)``); the fitness test
places each ``xi`` at the scale that maximises eq. 18 against the belief
(:meth:`~localization.mutual.particles.TeammateParticles.scale_search`).

Simplifications, stated: triangles not containing the observer are not used to expand solutions
(with four robots every teammate that sees the observer and one other teammate is in a triangle
with the observer), and an ``n``-intersection counts once, not ``C(n, 3)`` times.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np

from swarm_core.geometry import wrap_angle

__all__ = ["BearingTriangle", "bearing_solutions", "find_triangles", "three_intersections"]


@dataclass(frozen=True, slots=True)
class BearingTriangle:
    """A candidate triangle of robots ``labels = (a, b, c)``.

    ``features[(x, y)]`` is the index in ``B_x`` of the bearing to ``y``; ``bearing[(x, y)]`` its
    value. ``pose[y]``: ``(x, y, theta)`` of robot ``y`` in ``a``'s frame at unit ``|ab|``.
    ``rating`` counts its 3-intersections; ``residual_rad`` is ``| |s_a + s_b + s_c| - pi |``.
    """

    labels: tuple[int, int, int]
    features: dict[tuple[int, int], int]
    bearing: dict[tuple[int, int], float]
    pose: dict[int, np.ndarray]
    residual_rad: float
    rating: int = 0


def _ordered_pairs(m: int) -> np.ndarray:
    if m < 2:
        return np.zeros((0, 2), dtype=np.int64)
    i, j = np.nonzero(~np.eye(m, dtype=bool))
    return np.column_stack([i, j])


def find_triangles(
    bearings: dict[int, np.ndarray],
    tol_rad: float = math.radians(3.0),
    containing: int | None = None,
) -> list[BearingTriangle]:
    """Every candidate triangle among the labelled bearing sets (vectorised per triplet);
    with ``containing``, only the robot triples that include that label (the observer's:
    ``R - 1`` choose 2 triples instead of ``R`` choose 3)."""
    out: list[BearingTriangle] = []
    labels = sorted(bearings)
    for a, b, c in itertools.combinations(labels, 3):
        if containing is not None and containing not in (a, b, c):
            continue
        ba, bb, bc = (np.asarray(bearings[x], dtype=np.float64) for x in (a, b, c))
        pa, pb, pc = _ordered_pairs(len(ba)), _ordered_pairs(len(bb)), _ordered_pairs(len(bc))
        if not (len(pa) and len(pb) and len(pc)):
            continue
        # pa[:, 0] -> b, pa[:, 1] -> c; pb: (a, c); pc: (a, b)
        sa = wrap_angle(ba[pa[:, 1]] - ba[pa[:, 0]])  # beta_ac - beta_ab
        sb = wrap_angle(bb[pb[:, 0]] - bb[pb[:, 1]])  # beta_ba - beta_bc
        sc = wrap_angle(bc[pc[:, 1]] - bc[pc[:, 0]])  # beta_cb - beta_ca
        hits, resid = _triangle_candidates(sa, sb, sc, tol_rad)
        for (ia, ib, ic), r in zip(hits.tolist(), resid.tolist(), strict=True):
            f = {
                (a, b): int(pa[ia, 0]),
                (a, c): int(pa[ia, 1]),
                (b, a): int(pb[ib, 0]),
                (b, c): int(pb[ib, 1]),
                (c, a): int(pc[ic, 0]),
                (c, b): int(pc[ic, 1]),
            }
            beta = {k: float(bearings[k[0]][v]) for k, v in f.items()}
            al_b, al_c = abs(float(sb[ib])), abs(float(sc[ic]))
            ac = math.sin(al_b) / max(math.sin(al_c), 1e-9)  # law of sines, |ab| = 1
            pose = {
                a: np.zeros(3),
                b: np.array(
                    [
                        math.cos(beta[(a, b)]),
                        math.sin(beta[(a, b)]),
                        float(wrap_angle(beta[(a, b)] + math.pi - beta[(b, a)])),
                    ]
                ),
                c: np.array(
                    [
                        ac * math.cos(beta[(a, c)]),
                        ac * math.sin(beta[(a, c)]),
                        float(wrap_angle(beta[(a, c)] + math.pi - beta[(c, a)])),
                    ]
                ),
            }
            out.append(BearingTriangle((a, b, c), f, beta, pose, float(r)))
    return out


def _triangle_candidates_dense(
    sa: np.ndarray, sb: np.ndarray, sc: np.ndarray, tol_rad: float
) -> tuple[np.ndarray, np.ndarray]:
    """Reference of :func:`_triangle_candidates`: every ``(ia, ib, ic)`` (K, 3), row-major, whose
    signed differences share a sign and sum to ``+-pi`` within ``tol_rad``, and their residuals
    (K,). Memory and time ``Pa Pb Pc``."""
    total = sa[:, None, None] + sb[None, :, None] + sc[None, None, :]
    pos = (sa[:, None, None] > 0) & (sb[None, :, None] > 0) & (sc[None, None, :] > 0)
    neg = (sa[:, None, None] < 0) & (sb[None, :, None] < 0) & (sc[None, None, :] < 0)
    resid = np.where(pos, np.abs(total - np.pi), np.where(neg, np.abs(total + np.pi), np.inf))
    hits = np.argwhere(resid <= tol_rad)
    return hits, resid[tuple(hits.T)]


def _triangle_candidates(
    sa: np.ndarray, sb: np.ndarray, sc: np.ndarray, tol_rad: float
) -> tuple[np.ndarray, np.ndarray]:
    """The same as :func:`_triangle_candidates_dense`, same order, in ``Pa Pb log Pc``: for each
    ``(ia, ib)`` the third difference must lie within ``tol_rad`` of ``+-pi - sa - sb``, a window
    of the sorted ``sc`` (widened by 1e-9 rad, then the exact residual test of the reference)."""
    ab = sa[:, None] + sb[None, :]  # (Pa, Pb): the reference's first sum, same rounding
    order = np.argsort(sc, kind="stable")
    sorted_sc = sc[order]
    ia_all, ib_all, ic_all = [], [], []
    for sign, same in ((1.0, (sa[:, None] > 0) & (sb[None, :] > 0)),
                       (-1.0, (sa[:, None] < 0) & (sb[None, :] < 0))):  # fmt: skip
        ia, ib = np.nonzero(same)
        target = sign * np.pi - ab[ia, ib]
        lo = np.searchsorted(sorted_sc, target - tol_rad - 1e-9, side="left")
        hi = np.searchsorted(sorted_sc, target + tol_rad + 1e-9, side="right")
        count = hi - lo
        if not count.sum():
            continue
        pair = np.repeat(np.arange(len(ia)), count)
        offset = np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)
        ia_all.append(ia[pair])
        ib_all.append(ib[pair])
        ic_all.append(order[lo[pair] + offset])
    if not ia_all:
        return np.zeros((0, 3), dtype=np.int64), np.zeros(0)
    ia, ib, ic = (np.concatenate(v) for v in (ia_all, ib_all, ic_all))
    total = ab[ia, ib] + sc[ic]
    pos = (sa[ia] > 0) & (sb[ib] > 0) & (sc[ic] > 0)
    neg = (sa[ia] < 0) & (sb[ib] < 0) & (sc[ic] < 0)
    resid = np.where(pos, np.abs(total - np.pi), np.where(neg, np.abs(total + np.pi), np.inf))
    keep = resid <= tol_rad
    ia, ib, ic, resid = ia[keep], ib[keep], ic[keep], resid[keep]
    row_major = np.lexsort((ic, ib, ia))
    return np.column_stack([ia, ib, ic])[row_major], resid[row_major]


def three_intersections(
    tri: BearingTriangle, bearings: dict[int, np.ndarray], tol_rad: float = math.radians(3.0)
) -> int:
    """How many triples of the triangle's other rays (one per vertex) meet in one point."""
    a, b, c = tri.labels
    used = {x: {v for (y, _), v in tri.features.items() if y == x} for x in (a, b, c)}
    rays = []
    for x in (a, b, c):
        rest = np.array(
            [v for k, v in enumerate(np.asarray(bearings[x])) if k not in used[x]], dtype=float
        )
        if len(rest) == 0:
            return 0
        p = tri.pose[x]
        rays.append((p[:2], wrap_angle(rest + p[2])))
    (oa, da), (ob, db), (oc, dc) = rays
    # Intersections of every ray of a with every ray of b (in front of both).
    ua = np.column_stack([np.cos(da), np.sin(da)])  # (Ma, 2)
    ub = np.column_stack([np.cos(db), np.sin(db)])  # (Mb, 2)
    cross = ua[:, None, 0] * ub[None, :, 1] - ua[:, None, 1] * ub[None, :, 0]
    d = ob - oa
    with np.errstate(divide="ignore", invalid="ignore"):
        ta = (d[0] * ub[None, :, 1] - d[1] * ub[None, :, 0]) / cross
        tb = (d[0] * ua[:, None, 1] - d[1] * ua[:, None, 0]) / cross
    ok = np.isfinite(ta) & np.isfinite(tb) & (ta > 0) & (tb > 0)
    ta = np.where(ok, ta, 0.0)  # parallel rays: no intersection (masked by ok)
    q = oa + ta[..., None] * ua[:, None, :]  # (Ma, Mb, 2)
    ang = np.arctan2(q[..., 1] - oc[1], q[..., 0] - oc[0])  # (Ma, Mb)
    err = np.abs(wrap_angle(ang[..., None] - dc[None, None, :]))  # (Ma, Mb, Mc)
    return int((ok[..., None] & (err <= tol_rad)).any(axis=2).sum())


def _consistent(s: list[BearingTriangle], t: BearingTriangle) -> bool:
    """No set's feature for two robots, no robot on two features of one set."""
    for u in s:
        for (x, y), f in t.features.items():
            for (x2, y2), f2 in u.features.items():
                if x == x2 and ((y == y2) != (f == f2)):
                    return False
    return True


def bearing_solutions(
    bearings: dict[int, np.ndarray],
    observer: int = 0,
    tol_rad: float = math.radians(3.0),
    min_rating: int = 0,
    max_solutions: int = 200,
) -> list[dict[int, np.ndarray]]:
    """Algorithm 2's complete solutions: per solution ``label -> xi = (bearing, theta)``.

    Triangles containing ``observer`` with the best rating of their robot triple (and
    ``>= min_rating``) are the partial solutions; each is expanded with every consistent
    triangle containing the observer (a maximal consistent set is a complete solution), and the
    solutions that place the most robots with the most 3-intersections are returned.
    """
    tris = find_triangles(bearings, tol_rad, containing=observer)
    if not tris:
        return []
    for k, t in enumerate(tris):
        tris[k] = BearingTriangle(
            t.labels,
            t.features,
            t.bearing,
            t.pose,
            t.residual_rad,
            three_intersections(t, bearings, tol_rad),
        )
    best = max(t.rating for t in tris)
    if best < min_rating:
        return []
    # Keep, per robot triple, the triangles with that triple's best rating.
    top: dict[tuple, int] = {}
    for t in tris:
        top[t.labels] = max(top.get(t.labels, 0), t.rating)
    tris = [t for t in tris if t.rating == top[t.labels] and t.rating >= min_rating]
    tris.sort(key=lambda t: (-t.rating, t.residual_rad))
    solutions: list[list[BearingTriangle]] = []
    seen: set[frozenset] = set()

    def grow(current: list[BearingTriangle], start: int) -> None:
        if len(solutions) >= max_solutions:
            return
        extended = False
        for k in range(start, len(tris)):
            t = tris[k]
            if t.labels in {u.labels for u in current}:
                continue
            if _consistent(current, t):
                extended = True
                grow(current + [t], k + 1)
        if not extended:
            key = frozenset((kk, v) for u in current for kk, v in u.features.items())
            if not any(key < s for s in seen) and key not in seen:
                seen.add(key)
                solutions.append(current)

    for k, t in enumerate(tris):
        if len(solutions) >= max_solutions:
            break
        grow([t], k + 1)
    # Drop solutions strictly contained in others (not maximal).
    keys = [frozenset((kk, v) for u in s for kk, v in u.features.items()) for s in solutions]
    maximal = [s for s, key in zip(solutions, keys, strict=True) if not any(key < o for o in keys)]
    # The final rating (the thesis's last step): most robots placed, then most 3-intersections.
    score = [
        (len({lab for t in s for lab in t.labels}), sum(t.rating for t in s)) for s in maximal
    ]
    top_score = max(score)
    out = []
    for s, sc in zip(maximal, score, strict=True):
        if sc != top_score:
            continue
        xi: dict[int, list[np.ndarray]] = {}
        for t in s:
            frame = _observer_frame(t, observer)
            for lab in t.labels:
                if lab != observer:
                    xi.setdefault(lab, []).append(frame[lab])
        out.append(
            {
                lab: np.array(
                    [
                        math.atan2(np.sin(v)[:, 0].mean(), np.cos(v)[:, 0].mean()),
                        math.atan2(np.sin(v)[:, 1].mean(), np.cos(v)[:, 1].mean()),
                    ]
                )
                for lab, v in ((lab, np.array(vs)) for lab, vs in xi.items())
            }
        )
    return out


def _observer_frame(t: BearingTriangle, observer: int) -> dict[int, np.ndarray]:
    """``label -> (bearing, theta)`` of the triangle's other robots seen from ``observer``."""
    out = {}
    for y in t.labels:
        if y == observer:
            continue
        beta = t.bearing[(observer, y)]
        out[y] = np.array([beta, float(wrap_angle(beta + math.pi - t.bearing[(y, observer)]))])
    return out
