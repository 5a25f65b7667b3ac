"""Compiled PMB steps for many robots at once, the engine of :class:`~localization.pmb.PMBBank`.

The math is, formula for formula, that of the numpy reference
:class:`~localization.pmb.RobotCentricPMB` (its docstrings derive it), written as scalar loops;
``tests/localization/test_pmb_bank.py`` checks every robot against its own reference filter to
1e-10 on random call sequences for every model option. Detection probabilities, frame moves and
the Poisson reduction are the GM-PHD engine's own compiled helpers
(:mod:`localization.kernels`), so both filters share one implementation of the sensor models.

Calls are encoded exactly as for the GM-PHD bank (:mod:`localization.kernels`, built by
:class:`localization.bank._Batch`), and the driver's steps around the updates (the calls'
inputs in the filter's frame, the scan memory, the pending births, the padded tables) are that
bank's own helpers: this module holds the PMB's time update, association and updates only.
Model parameters: the GM-PHD's ``fparams`` / ``iparams``
(:func:`localization.kernels.pack_params` of ``config.phd``) plus ``pf`` / ``pi`` below.

State per robot ``r``: tracks ``(6, R, max_tracks)`` (rows ``r, x, y, Pxx, Pxy, Pyy``, first
``track_counts[r]`` columns), Poisson intensity ``(6, R, max_components)`` (first
``poisson_counts[r]``), pending measurement births ``(R, P, 2)``, and the scan memory
``(R, MEMORY_LEN)`` whose wide objects place part of the camera clutter (as the GM-PHD bank's;
kept only where ``PHDConfig.models_wide_objects``).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from .. import kernels as gk
from ..kernels import (
    _INDEX,
    _KINDS,
    _ODOMETRY,
    _ROBOTS,
    _STAMPS,
    ADVANCE,
    F_KAPPA_L,
    F_LIDAR_VAR,
    F_MERGE,
    F_MIN_RANGE,
    F_PRUNE,
    F_WIDE_CLUTTER,
    I_BIRTH_FIXED,
    I_BIRTH_MEASUREMENT,
    I_CAMERA_BIRTH,
    I_LIDAR_ONLY,
    I_MAX_COMPONENTS,
    LIDAR,
    PREDICT,
    _camera_pd,
    _lidar_pd,
    advance_clock,
    after_predict,
    camera_call_inputs,
    camera_clutter,
    camera_component,
    diffuse,
    frame_change,
    keep_measurement_births,
    lidar_call_inputs,
    lidar_component,
    lidar_exponent,
    predict_process_var,
    predict_with_births,
    reduce_table,
    robot_runs,
    set_fixed_birth,
    shift_means,
    shift_means_in_place,
    store_table,
)
from ..mixture import N_ROWS
from .config import PMBConfig

__all__ = ["pack_pmb_params", "apply_calls"]

# pf (float) and pi (int) indices
P_GATE_EXPONENT, P_BP_TOL, P_RECYCLE = 0, 1, 2
P_BP_ITER, P_MAX_TRACKS = 0, 1

_TINY = 1e-300
_FLOOR = 1e-100  # as localization.pmb.filter.FLOOR
_TWO_PI = 2.0 * math.pi


def pack_pmb_params(config: PMBConfig) -> tuple[np.ndarray, ...]:
    """``(fparams, iparams, sector_scaled, sector_params, pf, pi)`` of ``config``."""
    pf = np.array([-0.5 * config.gate_mahalanobis2, config.bp_tolerance, config.recycle_threshold])
    pi = np.array([config.bp_max_iterations, config.max_tracks], dtype=np.int64)
    return (*gk.pack_params(config.phd), pf, pi)


# ---------------------------------------------------------------------- time update
@njit(cache=True)
def _predict(tracks, nt, pois, npz, births, nb, odo, q, fp, ip):
    """Returns (tracks, nt, poisson, np) after the time update (``q``: its Q variance): the
    tracks' existences times ``P_s``, the Poisson intensity's as the GM-PHD's mixture."""
    t_out = tracks[:, :nt].copy()
    frame_change(t_out, nt, nt, odo, q, fp, ip)
    p_out, total = predict_with_births(pois, npz, births, nb, odo, q, fp, ip)
    return t_out, nt, p_out, total


# ---------------------------------------------------------------------- association
@njit(cache=True)
def lbp(psi, max_iterations, tolerance):
    """As :func:`~localization.pmb.association.lbp_marginals`: ``(p_track, p_unused)``.

    Sparse: the sweeps run over the gated-in pairs (``psi > 0``) only, in row-major order for
    the track sums and column-major order for the measurement sums. The reference's dense sums
    add exact zeros elsewhere, which changes no bit, so both give the same messages.
    """
    n, m = psi.shape
    # row-major edge list (CSR) and, per column, its edges in increasing row order
    n_edges = 0
    for i in range(n):
        for j in range(m):
            n_edges += psi[i, j] > 0.0
    row_ptr = np.zeros(n + 1, dtype=np.int64)
    col = np.empty(n_edges, dtype=np.int64)
    val = np.empty(n_edges)
    col_count = np.zeros(m + 1, dtype=np.int64)
    e = 0
    for i in range(n):
        for j in range(m):
            if psi[i, j] > 0.0:
                col[e] = j
                val[e] = psi[i, j]
                col_count[j + 1] += 1
                e += 1
        row_ptr[i + 1] = e
    for j in range(m):
        col_count[j + 1] += col_count[j]
    by_col = np.empty(n_edges, dtype=np.int64)
    fill = col_count[:m].copy()
    for e in range(n_edges):
        j = col[e]
        by_col[fill[j]] = e
        fill[j] += 1
    nu = np.ones(n_edges)
    a = np.empty(n_edges)
    mu = np.empty(n_edges)
    excl = np.empty(n_edges)
    if n_edges:
        for _ in range(max_iterations):
            for e in range(n_edges):
                a[e] = val[e] * nu[e]
            _exclusive_rows(a, row_ptr, excl, n)
            for e in range(n_edges):
                mu[e] = val[e] / (1.0 + excl[e])
            _exclusive_cols(mu, by_col, col_count, excl, m)
            delta = 0.0
            for e in range(n_edges):
                v = 1.0 / (1.0 + excl[e])
                delta = max(delta, abs(v - nu[e]))
                nu[e] = v
            if delta <= tolerance:
                break
    for e in range(n_edges):
        a[e] = val[e] * nu[e]
    _exclusive_rows(a, row_ptr, excl, n)
    p_track = np.zeros((n, m + 1))
    for i in range(n):
        denom = 1.0
        for e in range(row_ptr[i], row_ptr[i + 1]):
            denom += a[e]
        p_track[i, 0] = 1.0 / denom
        for e in range(row_ptr[i], row_ptr[i + 1]):
            p_track[i, 1 + col[e]] = a[e] / denom
    p_unused = np.empty(m)
    for j in range(m):
        s = 1.0
        for t in range(col_count[j], col_count[j + 1]):
            e = by_col[t]
            s += val[e] / (1.0 + excl[e])
        p_unused[j] = 1.0 / s
    return p_track, p_unused


@njit(cache=True)
def _exclusive_rows(a, row_ptr, out, n):
    """Per row, sum of the row's other edges: prefix then suffix (association.exclusive_sums)."""
    for i in range(n):
        pre = 0.0
        for e in range(row_ptr[i], row_ptr[i + 1]):
            out[e] = pre
            pre += a[e]
        suf = 0.0
        for e in range(row_ptr[i + 1] - 1, row_ptr[i] - 1, -1):
            out[e] += suf
            suf += a[e]


@njit(cache=True)
def _exclusive_cols(a, by_col, col_ptr, out, m):
    """Per column, sum of the column's other edges (rows in increasing order)."""
    for j in range(m):
        pre = 0.0
        for t in range(col_ptr[j], col_ptr[j + 1]):
            e = by_col[t]
            out[e] = pre
            pre += a[e]
        suf = 0.0
        for t in range(col_ptr[j + 1] - 1, col_ptr[j] - 1, -1):
            e = by_col[t]
            out[e] += suf
            suf += a[e]


# ---------------------------------------------------------------------- PMB update core
@njit(cache=True)
def _core(union, nt, k_stored, pd, lik, post_means, post_covs, kappa, pf, pi):
    """Track-oriented PMB update (RobotCentricPMB._update) given gated likelihoods.

    ``union (6, nt + K)`` = tracks then Poisson (K >= k_stored: a fixed birth may follow the
    stored Poisson components); ``lik (nt + K, M)`` is 0 for gated pairs; ``kappa (M,)`` the
    clutter intensity of each measurement. Returns
    ``(tracks (6, A), A, missed Poisson (6, k_stored), explained (M,))`` before recycling.
    """
    total = union.shape[1]
    k = total - nt
    m = lik.shape[1]
    pd_w = np.empty(total)
    for i in range(total):
        pd_w[i] = pd[i] * union[0, i]
    e = np.zeros(m)
    for kk in range(k):
        for j in range(m):
            e[j] += lik[nt + kk, j] * pd_w[nt + kk]
    c = np.empty(m)
    for j in range(m):
        c[j] = kappa[j] + e[j]
    miss = np.empty(nt)
    psi = np.empty((nt, m))
    for i in range(nt):
        miss[i] = max(1.0 - pd_w[i], _FLOOR)
        ratio = pd_w[i] / miss[i]
        for j in range(m):
            psi[i, j] = lik[i, j] * ratio / max(c[j], _FLOOR)
    p_track, p_unused = lbp(psi, pi[P_BP_ITER], pf[P_BP_TOL])
    n_born = 0
    for j in range(m):
        n_born += e[j] > 0.0
    out = np.empty((N_ROWS, nt + n_born))
    # existing tracks: missed (r0, prior) + detected (r = 1, updated), moment matched
    for i in range(nt):
        w0 = p_track[i, 0] * ((union[0, i] - pd_w[i]) / miss[i])
        tot = w0
        sx = w0 * union[1, i]
        sy = w0 * union[2, i]
        wdet = 0.0
        for j in range(m):
            w = p_track[i, 1 + j]
            if lik[i, j] > 0.0:
                tot += w
                wdet += w
                sx += w * post_means[0, i, j]
                sy += w * post_means[1, i, j]
        inv = 1.0 / max(tot, _TINY)
        mx, my = sx * inv, sy * inv
        dx, dy = union[1, i] - mx, union[2, i] - my
        cxx = w0 * dx * dx
        cxy = w0 * dx * dy
        cyy = w0 * dy * dy
        for j in range(m):
            if lik[i, j] > 0.0:
                w = p_track[i, 1 + j]
                dx, dy = post_means[0, i, j] - mx, post_means[1, i, j] - my
                cxx += w * dx * dx
                cxy += w * dx * dy
                cyy += w * dy * dy
        cxx += w0 * union[3, i] + wdet * post_covs[0, i]
        cxy += w0 * union[4, i] + wdet * post_covs[1, i]
        cyy += w0 * union[5, i] + wdet * post_covs[2, i]
        out[0, i] = min(tot, 1.0)  # marginals sum to 1 up to round-off
        out[1, i] = mx
        out[2, i] = my
        out[3, i] = cxx * inv
        out[4, i] = cxy * inv
        out[5, i] = cyy * inv
    # new tracks: measurement j unused by the tracks, explained by the Poisson intensity
    col = nt
    for j in range(m):
        if not e[j] > 0.0:
            continue
        tot = 0.0
        sx = 0.0
        sy = 0.0
        for kk in range(k):
            w = lik[nt + kk, j] * pd_w[nt + kk]
            if w > 0.0:
                tot += w
                sx += w * post_means[0, nt + kk, j]
                sy += w * post_means[1, nt + kk, j]
        inv = 1.0 / max(tot, _TINY)
        mx, my = sx * inv, sy * inv
        cxx = 0.0
        cxy = 0.0
        cyy = 0.0
        for kk in range(k):
            w = lik[nt + kk, j] * pd_w[nt + kk]
            if w > 0.0:
                dx, dy = post_means[0, nt + kk, j] - mx, post_means[1, nt + kk, j] - my
                cxx += w * (post_covs[0, nt + kk] + dx * dx)
                cxy += w * (post_covs[1, nt + kk] + dx * dy)
                cyy += w * (post_covs[2, nt + kk] + dy * dy)
        out[0, col] = p_unused[j] * e[j] / c[j]
        out[1, col] = mx
        out[2, col] = my
        out[3, col] = cxx * inv
        out[4, col] = cxy * inv
        out[5, col] = cyy * inv
        col += 1
    missed = union[:, nt : nt + k_stored].copy()
    for kk in range(k_stored):
        missed[0, kk] -= pd_w[nt + kk]
    explained = np.empty(m)
    for j in range(m):
        explained[j] = 1.0 - p_unused[j] + p_unused[j] * (e[j] / max(c[j], _TINY))
    return out, nt + n_born, missed, explained, p_unused, c


@njit(cache=True)
def _poisson_detections(union, nt, k, pd, lik, post_means, post_covs, p_unused, c):
    """The Poisson part's detected copies (RobotCentricPMB._update, ``births_to_poisson``):
    per measurement ``j`` the Poisson explains, per component ``kk`` it gates with, the
    updated copy of weight ``p_unused_j P_d w_kk g_kk,j / c_j``, measurement-major (6, D)."""
    m = lik.shape[1]
    count = 0
    for j in range(m):
        for kk in range(k):
            count += lik[nt + kk, j] * pd[nt + kk] * union[0, nt + kk] > 0.0
    out = np.empty((N_ROWS, count))
    col = 0
    for j in range(m):
        for kk in range(k):
            w = lik[nt + kk, j] * (pd[nt + kk] * union[0, nt + kk])
            if not w > 0.0:
                continue
            out[0, col] = p_unused[j] * w / c[j]
            out[1, col] = post_means[0, nt + kk, j]
            out[2, col] = post_means[1, nt + kk, j]
            out[3, col] = post_covs[0, nt + kk]
            out[4, col] = post_covs[1, nt + kk]
            out[5, col] = post_covs[2, nt + kk]
            col += 1
    return out


@njit(cache=True)
def _finish(tracks, n_tracks, missed, fp, ip, pf, pi):
    """Recycle (r < threshold, beyond max_tracks) into the Poisson, reduce it.
    Returns (tracks, nt, poisson, np)."""
    recycle = pf[P_RECYCLE]
    max_tracks = pi[P_MAX_TRACKS]
    keep = np.empty(n_tracks, dtype=np.bool_)
    n_keep = 0
    for i in range(n_tracks):
        keep[i] = tracks[0, i] >= recycle
        n_keep += keep[i]
    if n_keep > max_tracks:
        key = np.empty(n_tracks)
        for i in range(n_tracks):
            key[i] = -tracks[0, i] if keep[i] else 1.0
        order = np.argsort(key, kind="mergesort")
        keep[:] = False
        for t in range(max_tracks):
            keep[order[t]] = True
        n_keep = max_tracks
    k_missed = missed.shape[1]
    pois = np.empty((N_ROWS, k_missed + n_tracks - n_keep))
    pois[:, :k_missed] = missed
    t_out = np.empty((N_ROWS, n_keep))
    a = 0
    b = k_missed
    for i in range(n_tracks):
        if keep[i]:
            t_out[:, a] = tracks[:, i]
            a += 1
        else:
            pois[:, b] = tracks[:, i]
            b += 1
    p_out, n_p = reduce_table(pois, b, fp[F_PRUNE], fp[F_MERGE], ip[I_MAX_COMPONENTS])
    return t_out, n_keep, p_out, n_p


# ---------------------------------------------------------------------- measurement updates
@njit(cache=True)
def _union(tracks, nt, pois, npz, extra):
    """``[tracks | poisson | fixed birth]`` (6, nt + np (+1))."""
    out = np.empty((N_ROWS, nt + npz + extra))
    out[:, :nt] = tracks[:, :nt]
    out[:, nt : nt + npz] = pois[:, :npz]
    return out


@njit(cache=True)
def _lidar(tracks, nt, pois, npz, pts, nulls, fp, ip, sector_scaled, sector_params, pf, pi):
    m = pts.shape[0]
    fixed = ip[I_BIRTH_FIXED] and m > 0
    union = _union(tracks, nt, pois, npz, 1 if fixed else 0)
    if fixed:  # Perera 2021's birth joins the Poisson prior; its missed part is dropped
        set_fixed_birth(union, nt + npz, fp)
    total = union.shape[1]
    pd = _lidar_pd(union, total, nulls, fp, ip, sector_scaled, sector_params)
    r = fp[F_LIDAR_VAR]
    gate = pf[P_GATE_EXPONENT]
    lik = np.zeros((total, m))
    post_means = np.empty((2, total, m))  # read only where lik > 0
    post_covs = np.empty((3, total))
    for i in range(total):
        mx, my, h_xx, h_xy, h_yy, norm = lidar_component(union, i, r, post_covs)
        for h in range(m):
            exponent, e0, e1 = lidar_exponent(pts, h, mx, my, h_xx, h_xy, h_yy)
            if exponent < gate:
                continue
            lik[i, h] = math.exp(exponent) * norm
            post_means[0, i, h] = pts[h, 0] + (2.0 * r) * e0
            post_means[1, i, h] = pts[h, 1] + (2.0 * r) * e1
    out, n_out, missed, explained, _, _ = _core(
        union, nt, npz, pd, lik, post_means, post_covs, np.full(m, fp[F_KAPPA_L]), pf, pi
    )
    t, n_t, p, n_p = _finish(out, n_out, missed, fp, ip, pf, pi)
    return t, n_t, p, n_p, explained


@njit(cache=True)
def _camera(tracks, nt, pois, npz, brg, fp, ip, pf, pi, memory, ox, oy):
    """The camera update of the state seen from the camera at ``(ox, oy)`` (the filter's frame
    shifted by ``(-ox, -oy)``, which is how the scan ``memory``'s pose is read)."""
    m = brg.shape[0]
    union = _union(tracks, nt, pois, npz, 0)
    total = union.shape[1]
    pd = _camera_pd(union, total, fp)
    min_r2 = fp[F_MIN_RANGE] * fp[F_MIN_RANGE]
    gate = pf[P_GATE_EXPONENT]
    lik = np.zeros((total, m))
    post_means = np.empty((2, total, m))  # read only where lik > 0
    post_covs = np.empty((3, total))
    for i in range(total):
        x, y, g0, g1, predicted, norm, half_inv_s = camera_component(
            union, i, fp, min_r2, post_covs
        )
        for h in range(m):
            innov = brg[h] - predicted
            if innov >= math.pi or innov < -math.pi:
                innov = (innov + math.pi) % _TWO_PI - math.pi
            exponent = (innov * innov) * half_inv_s
            if exponent < gate:
                continue
            lik[i, h] = math.exp(exponent) * norm
            post_means[0, i, h] = x + g0 * innov
            post_means[1, i, h] = y + g1 * innov
    kappa = camera_clutter(brg, memory, ox, oy, fp)  # per bearing, as the GM-PHD's
    out, n_out, missed, explained, p_unused, c = _core(
        union, nt, npz, pd, lik, post_means, post_covs, kappa, pf, pi
    )
    if not ip[I_CAMERA_BIRTH]:
        return _finish(out, n_out, missed, fp, ip, pf, pi)
    # camera_birth="ray" (RobotCentricPMB._camera_update): the would-be new tracks stay in the
    # Poisson part as its updated copies, and the unexplained bearings' rays join it.
    det = _poisson_detections(union, nt, total - nt, pd, lik, post_means, post_covs, p_unused, c)
    k_missed = missed.shape[1]
    pois = np.empty((N_ROWS, k_missed + det.shape[1]))
    pois[:, :k_missed] = missed
    pois[:, k_missed:] = det
    t, n_t, p, n_p = _finish(out[:, :nt].copy(), nt, pois, fp, ip, pf, pi)
    p2, n_p2 = gk._with_ray_births(p, n_p, brg, explained, fp, ip)
    if n_p2 > n_p:
        p, n_p = reduce_table(p2, n_p2, fp[F_PRUNE], fp[F_MERGE], ip[I_MAX_COMPONENTS])
    return t, n_t, p, n_p


# ---------------------------------------------------------------------- driver
@njit(cache=True)
def _apply_call(q, state, calls, params):
    tracks, track_counts, poisson, poisson_counts, pending, pending_counts, clock, memories = state
    fp, ip, sector_scaled, sector_params, pf, pi = params
    r = calls[_ROBOTS][q]
    kind = calls[_KINDS][q]
    j = calls[_INDEX][q]
    nt = track_counts[r]
    npz = poisson_counts[r]
    tab = tracks[:, r, :nt]
    pois = poisson[:, r, :npz]
    memory = memories[r]
    if kind == ADVANCE:
        var = advance_clock(clock, r, calls[_STAMPS][j], fp, ip)
        diffuse(tab, nt, var)
        diffuse(pois, npz, var)
        return
    if kind == PREDICT:
        odo = calls[_ODOMETRY][j]
        q_var = predict_process_var(clock, r, fp, ip)
        t, n_t, p, n_p = _predict(
            tab, nt, pois, npz, pending[r], pending_counts[r], odo, q_var, fp, ip
        )
        after_predict(pending_counts, r, memory, odo)
    elif kind == LIDAR:
        # The profiles are kept for the wide objects' camera clutter only.
        pts, nul = lidar_call_inputs(calls, j, memory, fp[F_WIDE_CLUTTER] > 0.0, fp)
        t, n_t, p, n_p, explained = _lidar(
            tab, nt, pois, npz, pts, nul, fp, ip, sector_scaled, sector_params, pf, pi
        )
        if ip[I_BIRTH_MEASUREMENT]:
            keep_measurement_births(pending, pending_counts, r, pts, explained, fp)
    else:
        if ip[I_LIDAR_ONLY]:
            return
        # The bearing model from the camera's position (RobotCentricPMB.update_camera).
        brg, sx, sy = camera_call_inputs(calls, j)
        t, n_t, p, n_p = _camera(
            shift_means(tab, nt, -sx, -sy),
            nt,
            shift_means(pois, npz, -sx, -sy),
            npz,
            brg,
            fp,
            ip,
            pf,
            pi,
            memory,
            sx,
            sy,
        )
        shift_means_in_place(t, n_t, sx, sy)
        shift_means_in_place(p, n_p, sx, sy)
    store_table(tracks, track_counts, r, t, n_t)
    store_table(poisson, poisson_counts, r, p, n_p)


@njit(cache=True, parallel=True)
def apply_calls(state, calls, params):
    """Run the encoded calls on the bank state in place (robots in parallel, calls in order):
    ``state = (tracks, track_counts, poisson, poisson_counts, pending, pending_counts, clock,
    scan_memory)`` (module docstring), ``calls`` as :func:`localization.kernels.apply_calls`
    takes them, ``params`` :func:`pack_pmb_params`."""
    starts, n_groups = robot_runs(calls[_ROBOTS])
    for g in prange(n_groups):
        for q in range(starts[g], starts[g + 1]):
            _apply_call(q, state, calls, params)
