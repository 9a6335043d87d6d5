"""What the trainer starts from, whatever the point source: the cloud thinned to the training resolution, points
behind its depth edges for the views that look behind them, and the panorama's sky as a fixed environment at
infinity behind the Gaussians.

Disocclusions. Every pseudo-label is seen from the panorama centre, so the surface behind a depth edge (the
floor behind a bed's edge) has points only up to where the foreground hides it; a view from elsewhere looks past
the edge into a hole. ``disocclusion_fill`` extends the background behind the foreground, as layered-depth
methods do (Shade et al. 1998; Shih et al., 3D Photo Inpainting, 2020): each foreground pixel within
``fill_deg`` of an edge gets a second point on its ray at the background's distance, coloured like the
background. From the centre these points lie behind the foreground, which hides them once it is opaque; from
elsewhere they fill the hole with the background's continuation instead of nothing. While every Gaussian is
still see-through (3DGS's initial opacity 0.1) the centre sees some of them and training thins them out, so a
long enough run adds them only once the surface is opaque (``trainer.fill_join_step``; docs/benchmarks.md).

Sky. Sources drop sky pixels (no finite distance), so without help the trainer covers the sky with Gaussians
at arbitrary depths that look wrong from anywhere but the centre. A sky is infinitely far: its colour depends
on the ray direction only. ``sky_environment`` keeps the panorama's sky pixels as an ERP environment map (other
pixels take the colour of the nearest sky pixel, so sky that parallax reveals next to the horizon is sky
coloured); the trainer composites ``image + (1 - alpha) x background(ray)`` for every view. It is fixed (not
learned), so it cannot take over the geometry that the pseudo-labels, all seen from the centre, would let a
learned map explain; it costs no Gaussians and adds nothing to the depth term (alpha is unchanged).
"""

from __future__ import annotations

import math

import numpy as np

from ..geometry import PointCloud, erp_to_perspective
from ..geometry.sphere import direction_to_erp_pixel, erp_pixel_to_lonlat, lonlat_to_direction


def sky_environment(scene) -> np.ndarray | None:
    """[H, W, 3] float32 ERP in [0, 1]: the panorama's colour on ``scene.sky`` pixels, elsewhere the colour of the
    nearest sky pixel (Euclidean in pixels, no seam wrap); None when the scene has no sky pixel."""
    from scipy import ndimage

    sky = np.asarray(scene.sky, bool)
    if not sky.any():
        return None
    rgb = scene.rgb.astype(np.float32) / 255.0
    if sky.all():
        return rgb
    idx = ndimage.distance_transform_edt(~sky, return_distances=False, return_indices=True)
    return np.ascontiguousarray(rgb[idx[0], idx[1]])


def view_background(env: np.ndarray | None, camera) -> np.ndarray | None:
    """[h, w, 3] float32: the environment seen along ``camera``'s rays (direction only: the sky is at infinity)."""
    return None if env is None else erp_to_perspective(env, camera).astype(np.float32)


def points_for_resolution(res: int, fov_deg: float, pixels_per_point: float) -> int:
    """Initial points that give one point per ``pixels_per_point`` label pixels over the whole sphere: a
    ``res``² view of ``fov_deg`` has pixels of about (fov / res)² steradians at its centre."""
    pixel_sr = (math.radians(fov_deg) / res) ** 2
    return max(1, int(round(4 * math.pi / pixel_sr / pixels_per_point)))


def _cos_latitude_weight(xyz: np.ndarray) -> np.ndarray:
    """[N] float64: cos(latitude) of each point's direction from the origin, floored at 0.02 (1 at the origin).
    Float64, ``SPREAD_CHUNK`` points at a time (elementwise: the same values in any chunking)."""
    out = np.empty(len(xyz), np.float64)
    for i in range(0, len(xyz), SPREAD_CHUNK):
        x = xyz[i : i + SPREAD_CHUNK].astype(np.float64)
        r = np.linalg.norm(x, axis=1)
        w = np.divide(np.hypot(x[:, 0], x[:, 1]), r, out=np.ones_like(r), where=r > 0)
        np.maximum(w, 0.02, out=out[i : i + SPREAD_CHUNK])
    return out


def _thin_index(w: np.ndarray, n_points: int, seed: int) -> np.ndarray:
    """Sorted indices of ``n_points`` of len(w) items drawn without replacement with weights ``w`` [N] > 0, by the
    largest u^(1/w) keys (Efraimidis-Spirakis); all of them when there are at most ``n_points``."""
    if len(w) <= n_points:
        return np.arange(len(w))
    u = np.random.default_rng(seed).random(len(w))
    keys = np.log(np.maximum(u, 1e-300)) / w  # log of u^(1/w): same order, no underflow
    return np.sort(np.argpartition(-keys, n_points - 1)[:n_points])


def thin_cloud(pc: PointCloud, n_points: int, seed: int = 0) -> PointCloud:
    """At most ``n_points`` of ``pc``, drawn without replacement with weight cos(latitude) of each point's
    direction from the origin (the panorama centre), so a cloud back-projected from ERP pixels (whose solid
    angle is proportional to cos latitude) comes out evenly spread over the sphere; weights are floored at 0.02
    so points at the poles can be drawn. Weighted sampling by the largest u^(1/w) keys (Efraimidis-Spirakis).
    Returns ``pc`` itself when it already has at most ``n_points``."""
    if n_points < 1:
        raise ValueError(f"thin_cloud: n_points={n_points}: expected at least 1")
    if len(pc) <= n_points:
        return pc
    return pc.subset(_thin_index(_cos_latitude_weight(pc.xyz), n_points, seed))


DETAIL_LEVELS = 4  # coarsest detail-thinning level: sites 4^4 = 256 times sparser (16 times the spacing)
SPREAD_CHUNK = 1 << 21  # points per chunk of site_spread's float64 temporaries
DETAIL_MIN_POINTS = 6  # a site with fewer points is never called smooth (a plane through 3 fits any noise)


def _tangent_axes(m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit axes [S, 3] orthogonal to the unit directions ``m`` [S, 3] and to each other."""
    helper = np.where(np.abs(m[:, 2:3]) < 0.9, [[0.0, 0.0, 1.0]], [[1.0, 0.0, 0.0]])
    e1 = np.cross(m, helper)
    e1 /= np.maximum(np.linalg.norm(e1, axis=1, keepdims=True), 1e-300)  # 0 for a zero m (an empty site)
    return e1, np.cross(m, e1)


def site_spread(site: np.ndarray, n_sites: int, xyz: np.ndarray, rgb: np.ndarray) -> dict[str, np.ndarray]:
    """Per site of ``n_sites`` (``site`` [N] int64 in [0, n_sites)), over its points ``xyz`` [N, 3] (metres, seen
    from the origin) and ``rgb`` [N, 3] in [0, 1]: ``count`` [S] int64; ``colour_sd`` [S], the largest per-channel
    standard deviation; ``depth_sd`` [S], the relative standard deviation of the points' depth along their rays
    about the plane that fits them best, and ``normal`` [S, 3] that plane's unit normal. A plane seen from the
    origin has 1/z affine in the gnomonic coordinates of any axis (z along it): with m the site's mean direction,
    y = 1 / (x . m) is fitted by least squares as a + b u + c v, (u, v) = the point's tangent coordinates over its
    x . m, and depth_sd = sqrt(residual sum of squares / (count - 3)) / mean y (inf for 3 points or fewer, which
    any plane fits; NaN, and a NaN normal, for a site without points, or whose points are not all in front of the
    origin along m). Centred sums in float64, ``SPREAD_CHUNK`` points at a time (three passes: means, then the
    centred sums; only per-site arrays span the cloud, so an 8K cloud of 33.5M points needs no [N, 3] float64
    copy). A chunk's sums are added to the running per-site sums, so the values differ from one-piece sums by
    float rounding only."""
    count = np.bincount(site, minlength=n_sites)
    n = np.maximum(count, 1).astype(np.float64)
    chunks = [slice(i, i + SPREAD_CHUNK) for i in range(0, len(site), SPREAD_CHUNK)]

    def sums(values_of, k: int) -> np.ndarray:
        """[k, S]: per site, the sum over its points of each of the k per-point values ``values_of(chunk)``."""
        out = np.zeros((k, n_sites))
        for sl in chunks:
            out += np.stack([np.bincount(site[sl], v, minlength=n_sites) for v in values_of(sl)])
        return out

    def direction(sl):
        x = xyz[sl].astype(np.float64)
        return x, x / np.maximum(np.linalg.norm(x, axis=1), 1e-300)[:, None]

    # pass 1: colour means and the mean direction m of each site
    first = sums(lambda sl: [*rgb[sl].astype(np.float64).T, *direction(sl)[1].T], 6)
    mean_c, m = first[:3] / n, (first[3:] / n).T
    m /= np.maximum(np.linalg.norm(m, axis=1, keepdims=True), 1e-300)
    e1, e2 = _tangent_axes(m)

    def gnomonic(sl):
        """z (along the site's m), and u, v, y = 1/z of the chunk's points (z <= 0: z taken as 1)."""
        x, ms = xyz[sl].astype(np.float64), site[sl]
        z = np.einsum("nk,nk->n", x, m[ms])
        zs = np.where(z > 0, z, 1.0)
        return z, np.einsum("nk,nk->n", x, e1[ms]) / zs, np.einsum("nk,nk->n", x, e2[ms]) / zs, 1.0 / zs

    def second(sl):
        c, ms = rgb[sl].astype(np.float64), site[sl]
        z, u, v, y = gnomonic(sl)
        return [*((c[:, k] - mean_c[k][ms]) ** 2 for k in range(3)), z <= 0, u, v, y]

    # pass 2: the colour variances, who is behind the origin, the means of u, v, y
    sec = sums(second, 7)
    colour_var = sec[:3] / n
    ahead = sec[3] == 0  # every point in front of the origin along m
    mu, mv, my = sec[4] / n, sec[5] / n, sec[6] / n

    def third(sl):
        ms = site[sl]
        _, u, v, y = gnomonic(sl)
        uc, vc, yc = u - mu[ms], v - mv[ms], y - my[ms]
        return [uc * uc, uc * vc, vc * vc, uc * yc, vc * yc, yc * yc]

    # pass 3: the centred second moments of the plane fit
    suu, suv, svv, suy, svy, syy = sums(third, 6) / n
    G = np.stack([np.stack([suu, suv], -1), np.stack([suv, svv], -1)], -2)
    g = np.stack([suy, svy], -1)
    coef = np.einsum("sij,sj->si", np.linalg.pinv(G, rcond=1e-10, hermitian=True), g)
    ss = np.maximum(syy - np.einsum("si,si->s", coef, g), 0.0) * count  # residual sum of squares
    with np.errstate(divide="ignore", invalid="ignore"):
        depth_sd = np.where(count > 3, np.sqrt(ss / np.maximum(count - 3.0, 1.0)) / my, np.inf)
    # 1/z = (n1 u + n2 v + n_m) / k for the plane n . X = k: the normal is (b, c, intercept) in (e1, e2, m)
    intercept = my - coef[:, 0] * mu - coef[:, 1] * mv
    normal = coef[:, :1] * e1 + coef[:, 1:] * e2 + intercept[:, None] * m
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-300)
    out = {"count": count, "colour_sd": np.sqrt(np.max(colour_var, axis=0)), "depth_sd": depth_sd, "normal": normal}
    out["depth_sd"][~ahead] = np.nan
    out["normal"][~ahead | (count == 0)] = np.nan
    for k in ("colour_sd", "depth_sd"):
        out[k][count == 0] = np.nan
    return out


def thin_by_detail(
    pc: PointCloud, n_points: int, colour_tol: float, depth_tol: float, seed: int = 0, levels: int = DETAIL_LEVELS
) -> tuple[PointCloud, dict]:
    """``thin_cloud`` where the scene needs its density, fewer points where it does not: a region whose colour and
    geometry are smooth keeps one point per site of a sparser Fibonacci lattice over the directions from the
    origin, so the Gaussians made from them (3-NN scales) come out fewer and larger.

    Level l (``levels`` down to 1) has n / 4^l sites, n = min(``n_points``, len(pc)) (a spacing 2^l times the
    finest one); a site is smooth when at least DETAIL_MIN_POINTS points fall in it, their colours' largest
    per-channel standard deviation is at most ``colour_tol`` (in [0, 1]) and their depth's relative standard
    deviation about their best plane at most ``depth_tol`` (``site_spread``). From the coarsest level down, each
    smooth site takes its points not taken by a coarser level and keeps the one nearest its site's direction. The
    points no level takes are thinned as ``thin_cloud`` does, to ``n_points`` times their share of the cloud's
    cos-latitude weight (all of it when nothing is smooth, so the result is then ``thin_cloud``'s). Levels with
    fewer than 12 sites are skipped; ``colour_tol`` 0 skips them all (``thin_cloud`` itself). When a level ran,
    the cloud's ``normals`` are each coarse point's site plane normal (0 for the others), for
    ``GaussianModel.from_point_cloud``'s discs. -> (cloud, info: points kept, and per level, 0 the finest)."""
    if n_points < 1:
        raise ValueError(f"thin_by_detail: n_points={n_points}: expected at least 1")
    if not (colour_tol >= 0 and depth_tol >= 0):
        raise ValueError(f"thin_by_detail: colour_tol={colour_tol}, depth_tol={depth_tol}: expected both >= 0")
    from ..geometry import direction_to_lonlat, fibonacci_site_of, nearest_per_site

    lon, lat = np.empty(len(pc)), np.empty(len(pc))  # float64, from float64 directions made a chunk at a time
    for i in range(0, len(pc), SPREAD_CHUNK):
        lon[i : i + SPREAD_CHUNK], lat[i : i + SPREAD_CHUNK] = direction_to_lonlat(
            pc.xyz[i : i + SPREAD_CHUNK].astype(np.float64)
        )
    taken = np.zeros(len(pc), bool)
    normals = np.zeros((len(pc), 3), np.float32)  # a coarse point's site plane; 0: none
    keep, per_level = [], {}
    base = min(n_points, len(pc))
    for level in range(levels if colour_tol > 0 else 0, 0, -1):
        n_sites = base // 4**level
        if n_sites < 12:
            continue
        site, cos = fibonacci_site_of(pc.xyz, lon, lat, n_sites)
        spread = site_spread(site, n_sites, pc.xyz, pc.rgb)
        with np.errstate(invalid="ignore"):  # NaN spreads of empty sites compare False
            smooth = (
                (spread["count"] >= DETAIL_MIN_POINTS)
                & (spread["colour_sd"] <= colour_tol)
                & (spread["depth_sd"] <= depth_tol)
            )
        mine = np.flatnonzero(smooth[site] & ~taken)
        taken[mine] = True
        kept = mine[nearest_per_site(site[mine], cos[mine], n_sites)]
        keep.append(kept)
        normals[kept] = spread["normal"][site[kept]]
        per_level[level] = len(kept)
        del site, cos, spread, smooth, mine
    del lon, lat  # not needed below: the uniform thinning's arrays take their place
    rest = np.flatnonzero(~taken)
    w = _cos_latitude_weight(pc.xyz)
    n_rest = len(rest) if len(pc) <= n_points else int(round(n_points * w[rest].sum() / w.sum()))
    if len(rest) and n_rest:
        keep.append(rest[_thin_index(w[rest], n_rest, seed)])
    per_level[0] = len(keep[-1]) if len(rest) and n_rest else 0
    index = np.sort(np.concatenate(keep)) if keep else np.zeros(0, np.int64)
    out = pc.subset(index)
    if per_level.keys() - {0}:  # some level ran: the coarse points carry their plane's normal
        out.normals = normals[index]
    return out, {"points": len(index), "points_per_level": per_level}


def erp_zbuffer(pc: PointCloud, height: int, width: int) -> tuple[np.ndarray, np.ndarray]:
    """The cloud seen from the origin: per ERP pixel the nearest point's distance [H, W] float64 (inf where no
    point) and colour [H, W, 3] float32 (of equally near points, the last in the cloud's order). Each point's
    pixel and distance are computed from float64 coordinates ``SPREAD_CHUNK`` points at a time and written far
    to near in chunks of that order: the full-size arrays are the distances, flat pixel indices and the order
    (an 8K cloud's float64 [N, 3] copies would be 805 MB each)."""
    n = len(pc)
    r, pixel = np.empty(n), np.empty(n, np.int64)
    for i in range(0, n, SPREAD_CHUNK):
        x = pc.xyz[i : i + SPREAD_CHUNK].astype(np.float64)
        r[i : i + SPREAD_CHUNK] = np.linalg.norm(x, axis=1)
        rows, cols = direction_to_erp_pixel(x, height, width)  # a point at the origin: arbitrary, dropped below
        pixel[i : i + SPREAD_CHUNK] = np.clip(np.rint(rows).astype(np.int64), 0, height - 1) * width + (
            np.rint(cols).astype(np.int64) % width
        )
    ok = np.flatnonzero(r > 0)
    far_first = ok[np.argsort(-r[ok], kind="stable")]  # the nearest point of a pixel is written last
    del ok
    dist = np.full((height, width), np.inf)
    rgb = np.zeros((height, width, 3), np.float32)
    flat_d, flat_rgb = dist.reshape(-1), rgb.reshape(-1, 3)
    for i in range(0, len(far_first), SPREAD_CHUNK):  # in order, chunk after chunk: the last write still wins
        o = far_first[i : i + SPREAD_CHUNK]
        flat_d[pixel[o]] = r[o]
        flat_rgb[pixel[o]] = pc.rgb[o]
    return dist, rgb


def disocclusion_fill(pc: PointCloud, height: int, width: int, fill_deg: float = 10.0, jump: float = 0.1) -> PointCloud:
    """Points behind the depth edges of ``pc`` as seen from the origin (the panorama centre), on an ERP grid of
    ``height`` x ``width``. A pixel is behind an edge when a 4-neighbour's distance exceeds its own by more
    than ``jump`` (relative); it gets a point at that neighbour's distance (the nearest such, when several; on a
    tie the first of up, down, left, right) and colour. The background layer then grows into the foreground one
    pixel per step, for ``fill_deg`` degrees of longitude, each pixel taking the layer of a neighbour that is
    still ``jump`` beyond its own distance; a pixel gets at most one layer point. Columns wrap; pixels without a
    point (sky, thinned) neither receive nor give a layer. Returns the new points only (possibly none).

    Each step looks only at the neighbours of the pixels the previous step assigned (a layer never changes once
    set, so no other pixel can gain one): the work grows with the edges' length, not the image's size."""
    if not (fill_deg >= 0 and jump > 0):
        raise ValueError(f"disocclusion_fill: fill_deg={fill_deg}, jump={jump}: expected fill_deg >= 0, jump > 0")
    dist, rgb = erp_zbuffer(pc, height, width)
    flat = dist.ravel()
    layer_d = np.full(height * width, np.inf)
    origin = np.full(height * width, -1, np.int64)  # the background pixel whose distance and colour a layer has

    def neighbour(i: np.ndarray, k: int) -> np.ndarray:
        """Flat index of neighbour k (0 up, 1 down, 2 left, 3 right) of flat pixels ``i``; -1 beyond a pole."""
        r, c = np.divmod(i, width)
        r = r + (-1, 1, 0, 0)[k]
        c = (c + (0, 0, -1, 1)[k]) % width
        return np.where((r >= 0) & (r < height), r * width + c, -1)

    # sources: every pixel with a finite surface (first step), then the pixels the last step gave a layer
    sources = np.flatnonzero(np.isfinite(flat))
    source_d, source_origin = flat[sources], sources
    for _ in range(int(math.ceil(fill_deg / (360.0 / width)))):
        targets, values, origins = [], [], []
        for k in range(4):  # target t sees source s as its neighbour (1, 0, 3, 2)[k]: up first, as the rule reads
            # SPREAD_CHUNK sources at a time (the first step has every surface pixel, 33.5M at 8K), in order: the
            # lists come out as one piece would make them
            for i in range(0, len(sources), SPREAD_CHUNK):
                sd = source_d[i : i + SPREAD_CHUNK]
                t = neighbour(sources[i : i + SPREAD_CHUNK], (1, 0, 3, 2)[k])
                ok = t >= 0
                t_ok = np.where(ok, t, 0)
                ok &= np.isfinite(flat[t_ok]) & ~np.isfinite(layer_d[t_ok]) & (sd > flat[t_ok] * (1 + jump))
                targets.append(t[ok])
                values.append(sd[ok])
                origins.append(source_origin[i : i + SPREAD_CHUNK][ok])
        t, v, o = np.concatenate(targets), np.concatenate(values), np.concatenate(origins)
        if not len(t):
            break
        order = np.lexsort((np.arange(len(t)), v, t))  # by target, then nearest value, then neighbour order
        t, v, o = t[order], v[order], o[order]
        first = np.ones(len(t), bool)
        first[1:] = t[1:] != t[:-1]
        t, v, o = t[first], v[first], o[first]
        layer_d[t], origin[t] = v, o
        sources, source_d, source_origin = t, v, o
    at = np.flatnonzero(np.isfinite(layer_d))
    # the layer pixels' directions only (erp_directions' values there; the whole grid is 805 MB at 8K)
    rows, cols = np.divmod(at, width)
    xyz = lonlat_to_direction(*erp_pixel_to_lonlat(rows.astype(np.float64), cols.astype(np.float64), height, width))
    xyz *= layer_d[at][:, None]
    return PointCloud(xyz.astype(np.float32), rgb.reshape(-1, 3)[origin[at]])


def disocclusion_fill_reference(
    pc: PointCloud, height: int, width: int, fill_deg: float = 10.0, jump: float = 0.1
) -> dict[tuple[int, int], tuple[float, tuple]]:
    """``disocclusion_fill`` pixel by pixel, with plain loops: {(row, col): (distance, rgb)} of the layer."""
    dist, rgb = erp_zbuffer(pc, height, width)
    layer: dict[tuple[int, int], tuple[float, tuple]] = {}
    for _ in range(int(math.ceil(fill_deg / (360.0 / width)))):
        added = {}
        for r in range(height):
            for c in range(width):
                if (r, c) in layer or not np.isfinite(dist[r, c]):
                    continue
                best = None
                for rr, cc in ((r - 1, c), (r + 1, c), (r, (c - 1) % width), (r, (c + 1) % width)):
                    if not 0 <= rr < height:
                        continue
                    d, col = layer.get((rr, cc), (dist[rr, cc], tuple(rgb[rr, cc])))
                    if np.isfinite(d) and d > dist[r, c] * (1 + jump) and (best is None or d < best[0]):
                        best = (d, col)
                if best is not None:
                    added[(r, c)] = best
        if not added:
            break
        layer.update(added)
    return layer
