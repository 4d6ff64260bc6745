"""The coat band's compiled kernels (`icefarm.stages.surface.coat_kernel`) against numpy:
the tree's nearest points against pykdtree's, and the band's signed distance against the
numpy code it replaced (`_reference_phi`, below), on coats with sharp edges, rims and
walls."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from icefarm.spatial import nearest, point_index
from icefarm.stages.surface import coat_band
from icefarm.stages.surface.coat import CoatOptions, _Rim, coat_field
from icefarm.stages.surface.coat_band import Edges, Thickness, _signed
from icefarm.stages.surface.coat_kernel import BESIDE, PointTree, point_tree


def test_the_tree_finds_what_pykdtree_finds():
    rng = np.random.default_rng(4)
    # points on a wavy sheet, as surface samples are; queries near and far from it
    uv = rng.random((20_000, 2))
    points = np.c_[uv[:, 0], 0.05 * np.sin(9 * uv[:, 0]) * np.cos(7 * uv[:, 1]), uv[:, 1]]
    queries = np.r_[points[:3000] + 0.01 * rng.normal(size=(3000, 3)), rng.random((1000, 3)) * 1.4 - 0.2]
    tree = point_tree(points)
    for upper in (np.inf, 0.02):
        d, i = tree.nearest(queries, upper)
        d_ref, i_ref = nearest(point_index(points), queries, upper)
        assert np.array_equal(i, i_ref) and np.allclose(d, d_ref, rtol=1e-12, atol=0)
    # the same within tiles of eight around their mean, seeded by the mean's nearest
    centre = rng.random((500, 3)) * [1.0, 0.1, 1.0] - [0, 0.05, 0]
    tiles = (centre[:, None, :] + 0.004 * (np.indices((2, 2, 2)).reshape(3, -1).T - 0.5)[None]).reshape(-1, 3)
    _, seed = nearest(point_index(points), centre, 0.03)
    d, i = tree.nearest_in_tiles(tiles, seed, 8, 0.03 - 0.002 * np.sqrt(3))
    d_ref, i_ref = nearest(point_index(points), tiles, 0.03 - 0.002 * np.sqrt(3))
    assert np.array_equal(i, i_ref) and np.allclose(d, d_ref, rtol=1e-12, atol=0)
    # a tile far from a dense cluster: more leaves near it than it gathers (each of its
    # points then descends the tree on its own)
    cluster = rng.random((40_000, 3)) * 0.01
    far = (np.array([1.0, 1.0, 1.0]) + 0.004 * (np.indices((2, 2, 2)).reshape(3, -1).T - 0.5)).reshape(-1, 3)
    d, i = point_tree(cluster).nearest_in_tiles(far, np.zeros(1, dtype=np.int64), 8)
    d_ref, i_ref = nearest(point_index(cluster), far)
    assert np.array_equal(i, i_ref) and np.allclose(d, d_ref, rtol=1e-12, atol=0)
    assert point_tree(np.zeros((0, 3))) is None


def test_any_within_says_what_the_nearest_distance_says():
    rng = np.random.default_rng(5)
    points = rng.random((5000, 3)) * [1.0, 0.02, 1.0]  # a thin slab, as points along creases lie
    queries = np.r_[points[:2000] + 0.02 * rng.normal(size=(2000, 3)), rng.random((1000, 3)) * 1.4 - 0.2]
    radii = rng.random(len(queries)) * 0.03
    d_ref, _ = nearest(point_index(points), queries)
    radii[:50] = d_ref[:50]  # exactly at the nearest distance: within
    found = point_tree(points).any_within(queries, radii)
    assert np.array_equal(found, d_ref <= radii)
    assert 0.1 < found.mean() < 0.9
    assert not point_tree(points).any_within(np.zeros((0, 3)), np.zeros(0)).size


def test_the_kernels_compile_where_no_cache_folder_may_be_written(monkeypatch):
    """A read-only install on a node whose home is read-only too: numba finds nowhere to
    cache and refuses ``cache=True``; the kernels compile in each process instead."""
    import numba

    from icefarm.compiled import compiled

    real = numba.njit

    def refuse(*args, cache=False, **options):
        if cache:
            raise RuntimeError("cannot cache function 'f': no locator available for file 'f.py'")
        return real(*args, **options)

    monkeypatch.setattr(numba, "njit", refuse)
    assert compiled()(lambda x: 2 * x)(21) == 42


def _post():
    """A square post on the ground, a rivulet down one face's edge, the rest of that face wet."""
    post = trimesh.creation.box([0.08, 0.3, 0.08])
    post = post.subdivide().subdivide().subdivide()
    v = post.vertices
    wet = (v[:, 0] > 0.039) | (v[:, 1] > 0.149)
    return post, wet


def _sphere():
    sphere = trimesh.creation.icosphere(subdivisions=4, radius=0.1)
    return sphere, sphere.vertices[:, 1] > -0.05


@pytest.mark.parametrize("case, exclude", [("post", False), ("sphere", True), ("sphere", False)])
def test_the_band_kernel_gives_numpys_signed_distance(case, exclude, monkeypatch):
    mesh, wet = _post() if case == "post" else _sphere()
    sole = mesh.vertices[:, 1] < mesh.vertices[:, 1].min() + 0.01 if exclude else None
    thickness = np.where(wet, 0.004 + 0.01 * (mesh.vertices[:, 1] - mesh.vertices[:, 1].min()), 0.0)
    calls = []
    kernel = coat_band.band_phi

    def compare(*args):
        phi = kernel(*args)
        calls.append((args, phi))
        return phi

    monkeypatch.setattr(coat_band, "band_phi", compare)
    assert coat_field(mesh, thickness, wet, CoatOptions(0.003, edge=0.01), exclude=sole) is not None
    assert calls
    for args, phi in calls:
        ref = _reference(*args)
        # the nearest of two samples alike far (pykdtree and the kernel may pick either)
        same = np.abs(ref - phi) <= 1e-12
        assert same.mean() > 0.9999, f"{(~same).sum()} of {len(phi)} samples differ"
    kinds = np.concatenate([np.unique(a[11]) for a, _ in calls])
    assert 1 in kinds and 0 in kinds and (-1 in kinds) == exclude
    # sharp convex edges on the post, walls at the excluded sole, rims everywhere
    assert any(a[18] for a, _ in calls) == (case == "post")
    assert all(a[24] for a, _ in calls) and all(a[33] for a, _ in calls) == exclude


def _reference(points, per, seed, shared, seg, reach, tol, tol_shared, taper_end, samples, normals, kind,
               t_value, t_slope, t_low, t_high, depth, tree, has_edges, e_row, e_inward, e_level, e_across,
               e_across_level, has_rim, rim_tree, rim_seg, rim_a, rim_b, rim_ta, rim_tb, rim_normal, edge,
               has_wall, wet_index, wet_tree, blocked_tree, box_lo, box_hi):
    """The kernel's arguments to the numpy code it replaced (`_reference_phi`)."""
    thick = Thickness(t_value, t_slope, t_low, t_high)
    rim = _Rim(PointTree(*rim_tree, source=rim_tree[0]), rim_seg, rim_a, rim_b, rim_ta, rim_tb, rim_normal) \
        if has_rim else None
    edges = Edges(e_row, e_inward, e_level, e_across, e_across_level) if has_edges else None
    wall = (wet_index, point_index(samples[wet_index]), point_index(blocked_tree[0]), box_lo, box_hi) \
        if has_wall else None
    tree = point_index(samples)
    phi = np.empty(len(points))
    seed, flat, seg = (np.repeat(a, per)[:len(points)] for a in (seed, shared, seg))  # per tile: per point
    phi[flat] = _reference_phi(tree, samples, points[flat], normals, thick, kind, rim, edge, depth, reach, tol_shared,
                               seed[flat], seg[flat], taper_end=taper_end)
    phi[~flat] = _reference_phi(tree, samples, points[~flat], normals, thick, kind, rim, edge, depth, reach, tol,
                                wall=wall, taper_end=taper_end, edges=edges)
    return phi


def _reference_phi(tree, samples, points, normals, thick: Thickness, kind, rim, edge, depth, reach, tol, near=None,
                   seg=None, wall=None, taper_end=0.0, edges: Edges | None = None):
    """``phi`` (meters, positive inside the coat) at ``points`` (see `sample_band`), from
    their nearest ``samples`` (indices ``near``, -1 for none; queried in ``tree``, their
    `icefarm.spatial.point_index`, when not given).

    The points of a dry sample lie past the rim: the coat there tapers with the distance
    to the nearest rim segment, found per point or given (``seg``, -1: none near; the
    samples of a tile sharing one, `sample_band`). With ``wall`` (wet sample indices,
    a tree of the wet samples, one of the excluded ones, and the excluded ones' box widened
    by ``reach``: lowest and highest corners), the coat stops at the bisector between wet
    and excluded samples. The taper ends where it would be thinner than
    ``taper_end`` (meters). ``edges``: see `sample_band`.
    """
    if near is None:
        dist, near = nearest(tree, points, reach)
        found = np.flatnonzero(near >= 0)
        i = near[found]
        v = points[found] - samples[i]
        d_s = dist[found]
    else:
        found = np.flatnonzero(near >= 0)
        i = near[found]
        v = points[found] - samples[i]
        d_s = np.sqrt(np.einsum("kd,kd->k", v, v))
    phi = np.full(len(points), -reach)
    k = kind[i]
    past, over = (None, None) if edges is None else _bound(edges, i, points[found])
    d, sd, extra = _signed(v, normals[i], d_s, tol, past)
    if over is not None:  # near a convex edge the solid lies under both planes: the farther
        d = np.maximum(d, over)
    # The thickness's slope is carried no farther than the sample's reach: past a convex
    # corner, where a point's nearest sample may lie a centimetre to the side, the slopes
    # of a corner's small faces (0.4-0.5 m/m on a fence's picket tops) carried that far
    # disagreed by 6 mm between neighbouring lattice samples and left flecks of coat.
    lateral = v - sd[:, None] * normals[i]
    lateral *= np.minimum(1.0, tol / np.maximum(np.sqrt(np.einsum("kd,kd->k", lateral, lateral)), 1e-300))[:, None]
    t = np.where(k == 1, _at(thick, i, lateral), -np.inf)
    dry = np.flatnonzero(k == 0)
    if rim is not None and len(dry):
        foot = points[found[dry]] - sd[dry, None] * normals[i[dry]]
        j = rim.query(foot, edge) if seg is None else seg[found[dry]]
        dry, foot, j = dry[j >= 0], foot[j >= 0], j[j >= 0]
        d_rim, t_rim = _near(rim, foot, j)
        facing = np.einsum("kd,kd->k", normals[i[dry]], rim.normal[j]) > -0.5
        taper = t_rim * (1.0 - d_rim / edge)
        t[dry] = np.where(facing & (d_rim < edge) & (taper >= taper_end), taper, -np.inf)
    p = np.minimum(t - d, d + depth[i])
    # Under the sample's plane but past its reach the point may lie beside a convex edge,
    # outside the object: the coat's hidden inner part must not come out there. (Past a
    # sharp edge of the sample's face the plane across says how far out it lies.)
    beside = (sd < 0) & (extra > 0)
    if over is not None:
        beside &= ~np.isfinite(over)
    beside = np.flatnonzero(beside)
    p[beside] = np.minimum(p[beside], t[beside] - sd[beside] - BESIDE * extra[beside])
    if wall is not None:
        wet_index, wet_tree, blocked_tree, blocked_lo, blocked_hi = wall
        sel = np.flatnonzero(k != 0)  # nearest to a wet or an excluded sample
        q = points[found[sel]]
        # Only points in the excluded samples' box, widened by reach, can have one within
        # reach (the sole an object stands on is a small part of it: a query each was 7 %
        # of the band's time on Table 2's dragon).
        d_b = np.full(len(q), np.inf)
        boxed = np.ones(len(q), dtype=bool)
        for a in range(3):
            boxed &= (q[:, a] >= blocked_lo[a]) & (q[:, a] <= blocked_hi[a])
        boxed = np.flatnonzero(boxed)
        d_b[boxed] = nearest(blocked_tree, q[boxed], reach)[0]
        d_w = d_s[sel]
        cut = np.flatnonzero(k[sel] == -1)
        if len(cut):  # nearest to an excluded sample: the coat of the nearest wet one, walled
            d_b[cut] = np.minimum(d_b[cut], d_w[cut])
            d_cut, j = nearest(wet_tree, q[cut], reach)
            ok = j >= 0
            d_w[cut] = d_cut
            cut, j, d_cut = cut[ok], wet_index[j[ok]], d_cut[ok]
            past_j, over_j = (None, None) if edges is None else _bound(edges, j, q[cut])
            dj = _signed(q[cut] - samples[j], normals[j], d_cut, tol, past_j)[0]
            if over_j is not None:
                dj = np.maximum(dj, over_j)
            p[sel[cut]] = np.minimum(thick.value[j] - dj, dj + depth[j])
        p[sel] = np.minimum(p[sel], 0.5 * (d_b - d_w))
    phi[found] = np.where(np.isfinite(p) & (d < reach), p, -reach)
    return phi


def _at(thick: Thickness, i: np.ndarray, lateral: np.ndarray) -> np.ndarray:
    """The thickness of sample ``i`` (k,) carried ``lateral`` (k, 3) along its slope."""
    return np.clip(thick.value[i] + np.einsum("kd,kd->k", thick.slope[i], lateral), thick.low[i], thick.high[i])


def _bound(edges: Edges, i: np.ndarray, points: np.ndarray):
    """For ``points`` (k, 3) near sample ``i`` (k,): how far each lies past the edges along
    the sample's plane (meters, 0 where it does not or ``i`` has none), and its height over
    the planes across them (the most of them; -inf where none)."""
    past = np.zeros(len(points))
    over = np.full(len(points), -np.inf)
    sel = np.flatnonzero(edges.row[i] >= 0)
    if len(sel):
        r = edges.row[i[sel]]
        p = points[sel]
        off = edges.level[r, 0] - np.einsum("kd,kd->k", p, edges.inward[r, 0])
        up = np.einsum("kd,kd->k", p, edges.across[r, 0]) - edges.across_level[r, 0]
        for e in (1, 2):
            more = np.flatnonzero(np.isfinite(edges.level[r, e]))
            if len(more):
                rm, pm = r[more], p[more]
                off[more] = np.maximum(off[more], edges.level[rm, e] - np.einsum("kd,kd->k", pm, edges.inward[rm, e]))
                up[more] = np.maximum(up[more],
                                      np.einsum("kd,kd->k", pm, edges.across[rm, e]) - edges.across_level[rm, e])
        past[sel] = np.maximum(off, 0.0)
        over[sel] = up
    return past, over


def _near(rim: _Rim, foot: np.ndarray, j: np.ndarray):
    """Distance from ``foot`` (k, 3) to rim segment ``j`` (k,) and the coat's thickness at
    its nearest point there."""
    a, e = rim.a[j], rim.b[j] - rim.a[j]
    u = np.clip(np.einsum("kd,kd->k", foot - a, e) / np.maximum(np.einsum("kd,kd->k", e, e), 1e-300), 0, 1)
    off = foot - a - u[:, None] * e
    return np.sqrt(np.einsum("kd,kd->k", off, off)), rim.ta[j] + u * (rim.tb[j] - rim.ta[j])
