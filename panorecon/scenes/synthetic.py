"""Procedural synthetic scenes with ground truth, one per prompt of the paper's Table 1.

Each scene is a set of Open3D triangle meshes with solid procedural textures (colour is a function of the
3D surface point, so every viewpoint sees the same colour) and Lambertian shading from a fixed light.
Rendering is ray casting (Open3D ``RaycastingScene``): ERP panoramas and perspective views from any
position, with the exact ray distance of each pixel-centre ray. Sky is at infinite distance.
The panorama centre is the world origin, 1.6 m above the floor / ground.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import open3d as o3d

from ..geometry import PinholeCamera, erp_pixel_to_lonlat, lonlat_to_direction
from . import procedural as P
from .base import ErpRender, Scene, ViewRender
from .catalog import DEFAULT_WIDTH, SCENE_SEED, SYNTHETIC_SCENES, split_variant
from .variation import Draws, variant_rng

EYE_HEIGHT = 1.6  # metres above the floor / ground at the panorama centre
ERP_BAND_PIXELS = 1 << 21  # rays cast at once by render_erp
LIGHT = np.array([0.35, -0.25, 0.9]) / np.linalg.norm([0.35, -0.25, 0.9])


@dataclass
class Part:
    """One mesh and its texture."""

    mesh: o3d.geometry.TriangleMesh
    texture: P.Texture
    emissive: bool = False  # lamps, screens: unshaded


@dataclass
class SyntheticWorld:
    """Meshes + textures + sky; renders true images and distances from any position."""

    parts: list[Part]
    outdoor: bool
    seed: int
    ambient: float = 0.45
    light: np.ndarray = field(default_factory=lambda: LIGHT)  # unit direction towards the light (the sun)
    sky_horizon: tuple | np.ndarray = P.SKY_HORIZON  # outdoor sky RGB at the horizon and the zenith
    sky_zenith: tuple | np.ndarray = P.SKY_ZENITH
    cloudiness: float = 0.5
    variant: int | None = None  # K of a variant (bedroom@K), None for the base scene
    params: dict = field(default_factory=dict)  # the scene's parameters (defaults or drawn), JSON-serialisable
    redraws: int = 0  # draws of the variant discarded before this one (too little free space at the eye)
    _scene: o3d.t.geometry.RaycastingScene | None = field(default=None, repr=False)

    def _raycaster(self) -> o3d.t.geometry.RaycastingScene:
        if self._scene is None:
            rc = o3d.t.geometry.RaycastingScene()
            for part in self.parts:
                rc.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(part.mesh))
            self._scene = rc
        return self._scene

    def cast(self, origin: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Rays from ``origin`` [3] along unit ``directions`` [..., 3] -> (rgb float [..., 3] in [0, 1],
        distance float32 [...] metres, inf for no hit, sky bool [...])."""
        shape = directions.shape[:-1]
        d = directions.reshape(-1, 3).astype(np.float64)
        rays = np.concatenate([np.broadcast_to(np.asarray(origin, float), d.shape), d], 1).astype(np.float32)
        hit = self._raycaster().cast_rays(o3d.core.Tensor(rays))
        t = hit["t_hit"].numpy().astype(np.float64)
        gid = hit["geometry_ids"].numpy()
        normals = hit["primitive_normals"].numpy().astype(np.float64)
        sky = ~np.isfinite(t)
        rgb = np.zeros((len(d), 3))
        if sky.any():
            rgb[sky] = (
                P.sky_color(d[sky], self.seed, self.cloudiness, self.sky_horizon, self.sky_zenith)
                if self.outdoor
                else 0.0
            )
        p = np.asarray(origin, float) + d * np.where(sky, 0.0, t)[:, None]
        # normals face the viewer, so thin quads shade the same from either side of the room
        flip = np.einsum("ij,ij->i", normals, d) > 0
        normals[flip] *= -1
        for k, part in enumerate(self.parts):
            sel = (gid == k) & ~sky
            if not sel.any():
                continue
            albedo = part.texture(p[sel], normals[sel])
            if part.emissive:
                rgb[sel] = albedo
            else:
                lambert = np.clip(normals[sel] @ self.light, 0, None)
                # indoor: a soft second light from below-ish so floors and undersides are not flat
                fill = 0.25 * np.clip(normals[sel] @ np.array([-0.3, 0.5, -0.2]) / 0.62, 0, None)
                rgb[sel] = (
                    albedo * (self.ambient + (1 - self.ambient) * lambert + (0 if self.outdoor else fill))[:, None]
                )
        dist = np.where(sky, np.inf, t).astype(np.float32)
        return np.clip(rgb, 0, 1).reshape(shape + (3,)), dist.reshape(shape), sky.reshape(shape)

    def render_erp(self, height: int, position: np.ndarray | None = None) -> ErpRender:
        """ERP of ``height`` x 2*height from ``position`` (default: the panorama centre, the origin)."""
        origin = np.zeros(3) if position is None else np.asarray(position, float)
        rgb = np.empty((height, 2 * height, 3), np.uint8)
        dist = np.empty((height, 2 * height), np.float32)
        sky = np.empty((height, 2 * height), bool)
        rows = max(1, ERP_BAND_PIXELS // (2 * height))  # cast band by band: float64 temporaries of one band only
        cols = np.arange(2 * height, dtype=np.float64)
        for r0 in range(0, height, rows):
            rr, cc = np.meshgrid(np.arange(r0, min(r0 + rows, height), dtype=np.float64), cols, indexing="ij")
            band = lonlat_to_direction(*erp_pixel_to_lonlat(rr, cc, height, 2 * height))  # erp_directions' rows
            c, dist[r0 : r0 + rows], sky[r0 : r0 + rows] = self.cast(origin, band)
            rgb[r0 : r0 + rows] = _to_uint8(c)
        return ErpRender(rgb, dist, sky)

    def render_view(self, camera: PinholeCamera) -> ViewRender:
        rays = camera.world_rays()
        rgb, dist, sky = self.cast(camera.position, rays)
        depth_z = (dist * (rays @ camera.forward)).astype(np.float32)
        return ViewRender(_to_uint8(rgb), dist, depth_z, sky)

    def free_space_radius(self) -> float:
        """Distance from the origin to the nearest surface, less a 0.2 m margin (metres)."""
        d = self._raycaster().compute_distance(o3d.core.Tensor([[0.0, 0.0, 0.0]], dtype=o3d.core.float32)).numpy()[0]
        return float(max(d - 0.2, 0.0))

    def mesh(self) -> o3d.geometry.TriangleMesh:
        """All parts as one mesh, vertex colours = texture albedo at the vertices."""
        out = o3d.geometry.TriangleMesh()
        for part in self.parts:
            m = o3d.geometry.TriangleMesh(part.mesh)
            m.compute_vertex_normals()
            v, n = np.asarray(m.vertices), np.asarray(m.vertex_normals)
            m.vertex_colors = o3d.utility.Vector3dVector(np.clip(part.texture(v, n), 0, 1))
            out += m
        return out


def _to_uint8(rgb: np.ndarray) -> np.ndarray:
    return np.clip(np.round(rgb * 255), 0, 255).astype(np.uint8)


# ---------------------------------------------------------------- room helpers
def _room(size, floor_tex, wall_tex, ceiling_tex, wall_texes=None) -> list[Part]:
    """An enclosing room of ``size`` (x, y, z) metres, centred horizontally on the origin, floor at -EYE_HEIGHT."""
    lx, ly, lz = size
    x0, y0, z0 = -lx / 2, -ly / 2, -EYE_HEIGHT
    walls = [
        P.quad((x0, y0, z0), (lx, 0, 0), (0, 0, lz)),  # y = y0
        P.quad((x0, -y0, z0), (lx, 0, 0), (0, 0, lz)),  # y = -y0
        P.quad((x0, y0, z0), (0, ly, 0), (0, 0, lz)),  # x = x0
        P.quad((-x0, y0, z0), (0, ly, 0), (0, 0, lz)),  # x = -x0
    ]
    wall_texes = wall_texes or [wall_tex] * 4
    return [
        Part(P.quad((x0, y0, z0), (lx, 0, 0), (0, ly, 0)), floor_tex),
        Part(P.quad((x0, y0, z0 + lz), (lx, 0, 0), (0, ly, 0)), ceiling_tex),
    ] + [Part(w, t) for w, t in zip(walls, wall_texes)]


def _floor(z: float) -> float:
    return -EYE_HEIGHT + z


def _mirror(parts: list[Part], axis: int) -> None:
    """Reflect every part's mesh in the plane through the origin normal to ``axis`` (0: x, 1: y), in place."""
    for part in parts:
        v = np.asarray(part.mesh.vertices).copy()
        v[:, axis] *= -1
        part.mesh.vertices = o3d.utility.Vector3dVector(v)


def _indoor(parts: list[Part], seed: int, v: Draws) -> SyntheticWorld:
    """A room's world: its layout mirrored in x and/or y (drawn), the light's direction and the ambient level."""
    for axis, name in enumerate(("mirror_x", "mirror_y")):
        if v.flag(name):
            _mirror(parts, axis)
    ambient = v.uniform("ambient", 0.45, 0.35, 0.55)
    return SyntheticWorld(parts, outdoor=False, seed=seed, ambient=ambient, light=v.direction("light", LIGHT, 35, 75))


def _outdoor(parts: list[Part], seed: int, v: Draws) -> SyntheticWorld:
    """A landscape's world: ambient level, the sun's direction, the sky's colours and cloud cover."""
    return SyntheticWorld(
        parts,
        outdoor=True,
        seed=seed,
        ambient=v.uniform("ambient", 0.5, 0.4, 0.6),
        light=v.direction("sun", LIGHT, 20, 75),
        sky_horizon=v.color("sky_horizon", P.SKY_HORIZON, 0.08),
        sky_zenith=v.color("sky_zenith", P.SKY_ZENITH, 0.2),
        cloudiness=v.uniform("cloudiness", 0.5, 0.3, 0.7),
    )


def _texture_seed(seed: int, v: Draws) -> int:
    """The seed of a scene's procedural textures: ``seed`` for the base scene, offset for a variant."""
    return seed + v.integer("texture_seed_offset", 0, 1, 9999)


# ---------------------------------------------------------------- scenes
# Each builder takes the texture seed and the scene's parameters (``Draws``): at their defaults (the values
# written as the first argument) it is the base scene; a variant draws them within the ranges that follow.
def bedroom(seed: int, v: Draws) -> SyntheticWorld:
    seed = _texture_seed(seed, v)
    W, D, H = (
        v.uniform("width_m", 4.6, 4.0, 5.6),
        v.uniform("depth_m", 5.2, 4.4, 6.4),
        v.uniform("height_m", 2.7, 2.4, 3.2),
    )
    parts = _room(
        (W, D, H),
        P.wood(v.color("floor", [0.55, 0.36, 0.2]), seed=seed, axis=0),
        P.stripes(
            v.color("wallpaper_a", [0.86, 0.8, 0.7], 0.15),
            v.color("wallpaper_b", [0.76, 0.68, 0.58]),
            v.uniform("wallpaper_period_m", 0.35, 0.15, 0.7),
            seed=seed,
        ),
        P.noisy(v.color("ceiling", [0.93, 0.93, 0.9], 0.08), 0.12, 2, seed),
    )
    bed_c = (-W / 2 + 1.15, v.uniform("bed_y_m", 0.6, -0.4, 0.9))
    parts += [
        Part(
            P.box((bed_c[0], bed_c[1], _floor(0.2)), (2.1, 1.7, 0.4)),
            P.wood(v.color("bed_frame", [0.4, 0.25, 0.15]), seed=seed + 1),
        ),
        Part(
            P.box((bed_c[0], bed_c[1], _floor(0.5)), (2.0, 1.6, 0.22)),
            P.checker(
                v.color("bedding_a", [0.85, 0.85, 0.9], 0.15),
                v.color("bedding_b", [0.55, 0.62, 0.8], 0.4),
                v.uniform("bedding_check_m", 0.2, 0.1, 0.35),
                seed,
            ),
        ),
        Part(
            P.box((-W / 2 + 0.2, bed_c[1] - 0.4, _floor(0.72)), (0.3, 0.55, 0.18)),
            P.noisy(v.color("pillow_a", [0.95, 0.95, 0.95], 0.1), 0.08, 6, seed),
        ),
        Part(
            P.box((-W / 2 + 0.2, bed_c[1] + 0.4, _floor(0.72)), (0.3, 0.55, 0.18)),
            P.noisy(v.color("pillow_b", [0.95, 0.9, 0.85], 0.1), 0.08, 6, seed),
        ),
        Part(
            P.box((-W / 2 + 0.06, bed_c[1], _floor(0.75)), (0.1, 1.8, 1.5)),
            P.wood(v.color("headboard", [0.35, 0.2, 0.12]), seed=seed + 2, axis=2),
        ),
        # nightstands and lamps
        Part(
            P.box((-W / 2 + 0.3, bed_c[1] - 1.2, _floor(0.3)), (0.5, 0.45, 0.6)),
            P.wood(v.color("nightstand", [0.5, 0.32, 0.18]), seed=seed + 3),
        ),
        Part(P.cylinder((-W / 2 + 0.3, bed_c[1] - 1.2, _floor(0.6)), 0.05, 0.35), P.solid([0.2, 0.2, 0.2])),
        Part(
            P.cylinder((-W / 2 + 0.3, bed_c[1] - 1.2, _floor(0.95)), 0.18, 0.25),
            P.solid(v.color("lamp", [1.0, 0.93, 0.75], 0.2)),
            emissive=True,
        ),
    ]
    # wardrobe, desk, chair, rug, window, pictures
    wardrobe_y = -D / 2 + v.uniform("wardrobe_wall_gap_m", 1.0, 0.85, 1.6)
    desk_y = D / 2 - v.uniform("desk_wall_gap_m", 1.1, 0.8, 1.5)
    rug = (v.uniform("rug_x_m", 0.3, -0.4, 0.6), v.uniform("rug_y_m", -0.6, -1.0, 0.4))
    parts += [
        Part(
            P.box((W / 2 - 0.35, wardrobe_y, _floor(1.05)), (0.65, 1.6, 2.1)),
            P.wood(v.color("wardrobe", [0.62, 0.45, 0.3]), seed=seed + 4, axis=2),
        ),
        Part(
            P.box((W / 2 - 0.4, desk_y, _floor(0.74)), (0.7, 1.3, 0.05)),
            P.wood(v.color("desk", [0.45, 0.3, 0.2]), seed=seed + 5),
        ),
        Part(P.box((W / 2 - 0.4, desk_y, _floor(0.36)), (0.6, 0.1, 0.72)), P.solid([0.3, 0.22, 0.15])),
        Part(
            P.box((W / 2 - 1.0, desk_y, _floor(0.23)), (0.45, 0.45, 0.46)),
            P.noisy(v.color("chair", [0.6, 0.15, 0.12], 0.4), 0.1, 8, seed),
        ),
        Part(
            P.box((rug[0], rug[1], _floor(0.01)), (1.6, 2.2, 0.02)),
            P.patches(
                v.palette("rug", [[0.6, 0.2, 0.2], [0.8, 0.6, 0.3], [0.3, 0.3, 0.5], [0.9, 0.85, 0.7]], 0.4),
                v.uniform("rug_patch_m", 0.25, 0.12, 0.45),
                seed,
            ),
        ),
        Part(
            P.box(
                (v.uniform("window_x_m", 0.4, -W / 2 + 0.9, W / 2 - 1.0), D / 2 - 0.01, _floor(1.5)), (1.4, 0.03, 1.1)
            ),
            P.noisy(v.color("window", [0.55, 0.75, 0.95], 0.2), 0.2, 2, seed),
            emissive=True,
        ),
        Part(
            P.box(
                (v.uniform("picture_x_m", 0.4, -W / 2 + 0.6, W / 2 - 1.3), -D / 2 + 0.02, _floor(1.6)), (0.9, 0.03, 0.6)
            ),
            P.patches(v.palette("picture", [[0.2, 0.4, 0.2], [0.7, 0.5, 0.2], [0.3, 0.5, 0.7]], 0.5), 0.15, seed + 6),
        ),
    ]
    return _indoor(parts, seed, v)


def bathroom(seed: int, v: Draws) -> SyntheticWorld:
    seed = _texture_seed(seed, v)
    W, D, H = (
        v.uniform("width_m", 3.4, 3.0, 4.2),
        v.uniform("depth_m", 4.0, 3.5, 4.8),
        v.uniform("height_m", 2.6, 2.4, 3.0),
    )
    wall_tiles = P.tiles(
        v.color("wall_tiles", [0.82, 0.86, 0.88], 0.15),
        v.color("grout", [0.6, 0.6, 0.6], 0.3),
        v.uniform("wall_tile_m", 0.2, 0.1, 0.35),
        seed=seed,
    )
    parts = _room(
        (W, D, H),
        P.checker(
            v.color("floor_a", [0.15, 0.15, 0.17], 0.5),
            v.color("floor_b", [0.85, 0.85, 0.82], 0.15),
            v.uniform("floor_tile_m", 0.3, 0.2, 0.5),
            seed,
        ),
        wall_tiles,
        P.noisy([0.96, 0.96, 0.96], 0.04, 3, seed),
    )
    marble = P.noisy(v.color("marble", [0.92, 0.9, 0.86], 0.12), 0.25, 3, seed + 1)
    tub_y = v.uniform("tub_y_m", 0.4, -D / 2 + 0.9, D / 2 - 0.9)
    vanity_y = v.uniform("vanity_y_m", -0.6, -D / 2 + 0.75, D / 2 - 0.75)
    toilet_x = v.uniform("toilet_x_m", 0.8, -0.2, W / 2 - 0.7)
    parts += [
        # bathtub along the -x wall: outer shell and water surface
        Part(P.box((-W / 2 + 0.4, tub_y, _floor(0.28)), (0.75, 1.7, 0.56)), marble),
        Part(
            P.box((-W / 2 + 0.4, tub_y, _floor(0.5)), (0.6, 1.5, 0.1)),
            P.noisy(v.color("bath_water", [0.6, 0.8, 0.9], 0.15), 0.15, 5, seed),
            emissive=False,
        ),
        # vanity with basin, mirror, tap
        Part(
            P.box((W / 2 - 0.3, vanity_y, _floor(0.42)), (0.55, 1.2, 0.84)),
            P.wood(v.color("vanity", [0.3, 0.2, 0.14], 0.4), seed=seed + 2),
        ),
        Part(
            P.box((W / 2 - 0.3, vanity_y, _floor(0.87)), (0.6, 1.3, 0.06)),
            P.noisy(v.color("countertop", [0.15, 0.15, 0.15], 0.6), 0.3, 4, seed + 3),
        ),
        Part(P.cylinder((W / 2 - 0.3, vanity_y, _floor(0.9)), 0.2, 0.08), P.solid([0.97, 0.97, 0.97])),
        Part(
            P.box((W / 2 - 0.02, vanity_y, _floor(1.55)), (0.03, 1.1, 0.85)),
            P.noisy(v.color("mirror", [0.7, 0.75, 0.78], 0.15), 0.1, 1, seed),
            emissive=True,
        ),
        Part(P.cylinder((W / 2 - 0.1, vanity_y, _floor(0.9)), 0.02, 0.25), P.solid([0.75, 0.7, 0.5])),
        # toilet
        Part(P.cylinder((toilet_x, -D / 2 + 0.45, _floor(0)), 0.22, 0.42), P.solid([0.97, 0.97, 0.96])),
        Part(P.box((toilet_x, -D / 2 + 0.12, _floor(0.6)), (0.45, 0.2, 0.4)), P.solid([0.95, 0.95, 0.95])),
        # towel rail, towels, plant pot, bath mat
        Part(
            P.box(
                (v.uniform("towel_x_m", -0.4, -W / 2 + 0.5, W / 2 - 0.5), D / 2 - 0.06, _floor(1.0)), (0.7, 0.06, 0.6)
            ),
            P.stripes(
                v.color("towel_a", [0.85, 0.5, 0.3], 0.4),
                v.color("towel_b", [0.95, 0.9, 0.8], 0.1),
                0.1,
                axis=2,
                seed=seed,
            ),
        ),
        Part(
            P.cylinder((-0.9, -D / 2 + 0.35, _floor(0)), 0.16, 0.35),
            P.noisy(v.color("pot", [0.6, 0.35, 0.25], 0.3), 0.1, 6, seed),
        ),
        Part(
            P.sphere((-0.9, -D / 2 + 0.35, _floor(0.6)), 0.28),
            P.noisy(v.color("plant", [0.2, 0.5, 0.2], 0.3), 0.35, 12, seed + 4),
        ),
        Part(
            P.box((-0.5, tub_y, _floor(0.01)), (0.6, 0.9, 0.02)),
            P.checker(v.color("mat_a", [0.3, 0.5, 0.6], 0.5), v.color("mat_b", [0.85, 0.85, 0.8], 0.1), 0.1, seed),
        ),
        Part(
            P.box(
                (v.uniform("window_x_m", 0.0, -W / 2 + 0.5, W / 2 - 0.5), D / 2 - 0.02, _floor(2.05)), (0.6, 0.03, 0.4)
            ),
            P.noisy(v.color("window", [0.6, 0.8, 1.0], 0.2), 0.1, 2, seed),
            emissive=True,
        ),
    ]
    return _indoor(parts, seed, v)


def library(seed: int, v: Draws) -> SyntheticWorld:
    seed = _texture_seed(seed, v)
    rng = np.random.default_rng(seed)
    W, D, H = (
        v.uniform("width_m", 9.0, 8.4, 10.5),
        v.uniform("depth_m", 11.0, 9.6, 12.5),
        v.uniform("height_m", 4.2, 3.8, 5.0),
    )
    parts = _room(
        (W, D, H),
        P.wood(v.color("floor", [0.45, 0.28, 0.16]), seed=seed, axis=1),
        P.noisy(v.color("walls", [0.85, 0.8, 0.68], 0.15), 0.08, 2, seed),
        P.tiles(v.color("ceiling", [0.8, 0.78, 0.7], 0.1), [0.5, 0.45, 0.4], 1.0, 0.05, seed),
    )
    book = v.uniform("book_width_m", 0.05, 0.03, 0.08)
    spines = P.patches(
        v.palette(
            "book_spines",
            [
                [0.55, 0.1, 0.1],
                [0.1, 0.25, 0.45],
                [0.15, 0.4, 0.2],
                [0.75, 0.6, 0.3],
                [0.3, 0.15, 0.3],
                [0.85, 0.8, 0.7],
                [0.2, 0.2, 0.2],
            ],
            0.4,
        ),
        np.array([book, book, 0.34]),
        seed,
    )
    shelf_wood = P.wood(v.color("shelf_wood", [0.35, 0.2, 0.1]), seed=seed + 1)
    # shelving along the long walls and free-standing stacks
    pitch = v.uniform("wall_shelf_pitch_m", 2.6, 2.3, (D - 2.65) / 3)  # four 2.2 m shelves fit the wall
    for side in (-1, 1):
        for k in range(4):
            y = -D / 2 + 1.5 + k * pitch
            parts.append(Part(P.box((side * (W / 2 - 0.2), y, _floor(1.2)), (0.35, 2.2, 2.4)), spines))
            parts.append(Part(P.box((side * (W / 2 - 0.2), y, _floor(2.45)), (0.4, 2.3, 0.1)), shelf_wood))
    stack_x, stack_y = v.uniform("stack_x_m", 2.2, 1.9, 2.5), v.uniform("stack_y_m", 3.5, 3.0, D / 2 - 0.9)
    for x in (-stack_x, stack_x):
        for y in (-stack_y, stack_y):
            parts.append(Part(P.box((x, y, _floor(1.0)), (2.4, 0.5, 2.0)), spines))
            parts.append(Part(P.box((x, y, _floor(2.05)), (2.5, 0.55, 0.1)), shelf_wood))
    # reading tables with chairs and green lamps
    table_wood, chair = v.color("table", [0.4, 0.22, 0.12]), v.color("chair", [0.5, 0.12, 0.1], 0.4)
    lamp = v.color("lamp", [0.1, 0.45, 0.2], 0.5)
    for y in (v.uniform("table0_y_m", -1.0, -1.4, -0.8), v.uniform("table1_y_m", 1.2, 1.0, 1.6)):
        parts.append(Part(P.box((0.0, y, _floor(0.76)), (2.0, 0.9, 0.06)), P.wood(table_wood, seed=seed + 2)))
        parts.append(Part(P.box((0.0, y, _floor(0.37)), (1.8, 0.1, 0.74)), shelf_wood))
        parts.append(Part(P.cylinder((0.5 * rng.choice([-1, 1]), y, _floor(0.79)), 0.12, 0.3), P.solid(lamp)))
        for x in (-0.6, 0.6):
            parts.append(Part(P.box((x, y + 0.75, _floor(0.23)), (0.42, 0.42, 0.46)), P.noisy(chair, 0.1, 8, seed)))
    parts.append(
        Part(
            P.box(
                (v.uniform("window_x_m", 0.0, -W / 2 + 2.0, W / 2 - 2.0), -D / 2 + 0.02, _floor(2.8)), (3.0, 0.03, 1.6)
            ),
            P.noisy(v.color("window", [0.6, 0.75, 0.95], 0.2), 0.2, 2, seed),
            emissive=True,
        )
    )
    return _indoor(parts, seed, v)


def exhibition_hall(seed: int, v: Draws) -> SyntheticWorld:
    seed = _texture_seed(seed, v)
    rng = np.random.default_rng(seed)
    W, D, H = (
        v.uniform("width_m", 14.0, 12.5, 16.0),
        v.uniform("depth_m", 18.0, 15.5, 21.0),
        v.uniform("height_m", 5.0, 4.4, 6.0),
    )
    parts = _room(
        (W, D, H),
        P.tiles(
            v.color("floor", [0.75, 0.74, 0.72], 0.2),
            [0.45, 0.45, 0.45],
            v.uniform("floor_tile_m", 1.2, 0.8, 1.6),
            0.03,
            seed,
        ),
        P.noisy(v.color("walls", [0.95, 0.95, 0.93], 0.1), 0.04, 1, seed),
        P.noisy([0.9, 0.9, 0.92], 0.05, 1, seed),
    )
    # large posters on the walls, each moved along its wall
    for i, (x, y, normal_x) in enumerate(
        [
            (-W / 2 + 0.03, -5, True),
            (-W / 2 + 0.03, 3, True),
            (W / 2 - 0.03, -2, True),
            (W / 2 - 0.03, 5, True),
            (-3, D / 2 - 0.03, False),
            (3, -D / 2 + 0.03, False),
        ]
    ):
        along = v.uniform(f"poster{i}_shift_m", 0.0, -1.0, 1.0)
        x, y = (x, y + along) if normal_x else (x + along, y)
        size = (0.04, 2.6, 3.2) if normal_x else (2.6, 0.04, 3.2)
        pal = rng.uniform(0.1, 0.95, size=(5, 3))
        parts.append(Part(P.box((x, y, _floor(2.4)), size), P.patches(pal, 0.45, seed + 10 + i, 0.05)))
    # glass display cases (tinted boxes on dark plinths) and art installations on pedestals
    glass = v.color("glass", [0.7, 0.85, 0.88], 0.15)
    for i, (x, y) in enumerate([(-3.5, -3.5), (3.5, -3.0), (-3.0, 4.0), (4.0, 3.5)]):
        x, y = x + v.uniform(f"case{i}_dx_m", 0.0, -0.6, 0.6), y + v.uniform(f"case{i}_dy_m", 0.0, -0.6, 0.6)
        parts.append(Part(P.box((x, y, _floor(0.45)), (1.4, 0.8, 0.9)), P.solid([0.18, 0.18, 0.2])))
        parts.append(Part(P.box((x, y, _floor(1.3)), (1.3, 0.7, 0.8)), P.noisy(glass, 0.12, 3, seed + i)))
    for i, (x, y) in enumerate([(0.0, -5.0), (-5.0, 0.5), (5.0, 0.0), (0.5, 6.0)]):
        x, y = x + v.uniform(f"pedestal{i}_dx_m", 0.0, -0.5, 0.5), y + v.uniform(f"pedestal{i}_dy_m", 0.0, -0.5, 0.5)
        parts.append(Part(P.cylinder((x, y, _floor(0)), 0.45, 1.0), P.noisy([0.9, 0.9, 0.88], 0.06, 4, seed)))
        shape = [
            P.sphere((x, y, _floor(1.55)), 0.5),
            P.torus((x, y, _floor(1.7)), 0.5, 0.15),
            P.box((x, y, _floor(1.6)), (0.6, 0.6, 1.2), yaw=0.6),
            P.sphere((x, y, _floor(1.4)), 0.35),
        ][i]
        parts.append(Part(shape, P.noisy(rng.uniform(0.2, 0.9, 3), 0.35, 6, seed + 20 + i)))
    # spotlights on a ceiling track
    spot = v.color("spotlight", [1.0, 0.97, 0.85], 0.2)
    for x in np.linspace(-5, 5, 6):
        parts.append(Part(P.box((x, 0, _floor(H - 0.1)), (0.12, 12.0, 0.08)), P.solid([0.15, 0.15, 0.15])))
        for y in (-4.0, 0.0, 4.0):
            parts.append(Part(P.cylinder((x, y, _floor(H - 0.45)), 0.12, 0.3), P.solid(spot), emissive=True))
    return _indoor(parts, seed, v)


def mountain(seed: int, v: Draws) -> SyntheticWorld:
    seed = _texture_seed(seed, v)
    peak, scale = v.uniform("peak_m", 1500.0, 900.0, 2200.0), v.uniform("ridge_scale_m", 900.0, 600.0, 1400.0)
    sharpness, bumps = v.uniform("ridge_exponent", 1.5, 1.2, 2.0), v.uniform("foreground_bumps_m", 3.0, 1.5, 5.0)

    def h(x, y):
        r = np.hypot(x, y)
        p = np.stack([x / scale, y / scale, np.full_like(x, seed * 0.37)], 1)
        ridge = 1 - np.abs(2 * P.fbm(p, 6, seed) - 1)  # ridged noise: sharp crests
        amp = peak * np.clip((r - 80) / 1400, 0, 1) ** 1.1
        local = (
            bumps
            * (P.fbm(np.stack([x / 40, y / 40, np.zeros_like(x)], 1), 3, seed + 1) - 0.5)
            * np.clip((r - 8) / 30, 0, 1)
        )
        return -EYE_HEIGHT + amp * ridge**sharpness + local

    terrain = P.heightfield(h, 1.0, 6000.0, 180, 400)
    terrain.compute_triangle_normals()
    snow = v.uniform("snow_line_scale", 1.0, 0.7, 1.4)  # scales the heights of the colour bands
    tex = P.by_height(
        [
            (-10, v.color("meadow", (0.35, 0.45, 0.2), 0.2)),
            (150 * snow, v.color("forest", (0.3, 0.4, 0.2), 0.2)),
            (350 * snow, v.color("scree", (0.45, 0.4, 0.33), 0.15)),
            (600 * snow, v.color("rock", (0.55, 0.52, 0.5), 0.15)),
            (800 * snow, (0.95, 0.95, 0.97)),
            (2000, (1.0, 1.0, 1.0)),
        ],
        slope_color=v.color("cliff", (0.42, 0.38, 0.34), 0.15),
        seed=seed,
    )
    return _outdoor([Part(terrain, tex)], seed, v)


def grassland(seed: int, v: Draws) -> SyntheticWorld:
    seed = _texture_seed(seed, v)
    rng = np.random.default_rng(seed)
    hills, scale = v.uniform("hill_height_m", 40.0, 15.0, 80.0), v.uniform("hill_scale_m", 250.0, 150.0, 400.0)

    def h(x, y):
        r = np.hypot(x, y)
        p = np.stack([x / scale, y / scale, np.full_like(x, 0.5)], 1)
        return -EYE_HEIGHT + hills * P.fbm(p, 5, seed) * np.clip((r - 10) / 400, 0, 1) - 0.0

    terrain = P.heightfield(h, 0.5, 4000.0, 160, 360)
    grass = P.by_height(
        [
            (-5, v.color("grass_low", (0.35, 0.55, 0.15), 0.2)),
            (15, v.color("grass_mid", (0.45, 0.6, 0.2), 0.2)),
            (40, v.color("grass_high", (0.55, 0.6, 0.3), 0.2)),
        ],
        seed=seed,
        jitter=0.6,
    )
    parts = [Part(terrain, grass)]
    # yurts and a fence line scattered on the steppe
    stripe, felt = v.color("yurt_stripe", [0.7, 0.3, 0.25], 0.4), v.color("yurt_felt", [0.9, 0.88, 0.82], 0.1)
    for _ in range(v.integer("yurts", 5, 2, 9)):
        a, r = rng.uniform(0, 2 * np.pi), rng.uniform(15, 60)
        x, y = r * np.cos(a), r * np.sin(a)
        z = float(h(np.array([x]), np.array([y]))[0])
        parts.append(
            Part(P.cylinder((x, y, z - 0.3), 2.5, 2.3), P.stripes([0.95, 0.95, 0.92], stripe, 1.0, axis=2, seed=seed))
        )
        parts.append(Part(P.sphere((x, y, z + 2.0), 2.5), P.noisy(felt, 0.1, 2, seed)))
    fence_y = v.uniform("fence_distance_m", 12.0, 7.0, 25.0) * (-1 if v.flag("fence_behind") else 1)
    fence_x0, posts = v.uniform("fence_start_x_m", -20.0, -40.0, -5.0), v.integer("fence_posts", 24, 10, 36)
    post = P.wood(v.color("fence", [0.45, 0.3, 0.18], 0.3), seed=seed)
    for k in range(posts):
        x = fence_x0 + 2.5 * k
        parts.append(
            Part(P.box((x, fence_y, float(h(np.array([x]), np.array([fence_y]))[0]) + 0.5), (0.12, 0.12, 1.2)), post)
        )
    return _outdoor(parts, seed + 1, v)


def beach(seed: int, v: Draws) -> SyntheticWorld:
    seed = _texture_seed(seed, v)
    rng = np.random.default_rng(seed)
    dunes, slope = v.uniform("dune_height_m", 2.5, 1.0, 4.0), v.uniform("shore_slope", 0.1, 0.06, 0.15)
    swell, chop = v.uniform("swell_m", 0.15, 0.05, 0.3), v.uniform("chop_m", 0.08, 0.03, 0.15)
    sea_level = v.uniform("sea_level_m", -0.35, -0.5, -0.2)  # below the sand at the shore line (x = 0)

    def sand(x, y):
        # the shore runs along y; sand rises inland (-x), dips under the sea (+x)
        dune = dunes * P.fbm(np.stack([x / 30, y / 30, np.zeros_like(x)], 1), 4, seed) * np.clip(-x / 40, 0, 1)
        return -EYE_HEIGHT - slope * x + dune

    def water(x, y):
        return (
            -EYE_HEIGHT
            + sea_level
            + swell * np.sin(0.9 * x + 0.2 * y)
            + chop * np.sin(2.3 * x - 1.1 * y + 1.0)
            + 0.4 * (P.fbm(np.stack([x / 12, y / 12, np.zeros_like(x)], 1), 3, seed + 3) - 0.5)
        )

    sea = P.heightfield(water, 0.5, 5000.0, 170, 360)
    # keep only the sea side so the water does not cover the beach
    verts = np.asarray(sea.vertices)
    keep = verts[:, 0] > -2.0
    sea.remove_vertices_by_mask(~keep)
    sand_c, sea_c = v.color("sand", [0.86, 0.76, 0.55], 0.15), np.array(v.color("sea", [0.1, 0.35, 0.5], 0.3))
    parts = [
        Part(
            P.heightfield(sand, 0.5, 3000.0, 150, 360),
            lambda p, n: P.noisy(sand_c, 0.12, 3, seed)(p, n) * (0.85 + 0.3 * P.fbm(p * 9, 2, seed + 5))[:, None],
        ),
        Part(
            sea,
            lambda p, n: np.clip(
                sea_c
                + 0.35 * np.clip(n[:, :1] * 0 + (1 - n[:, 2:3]) * 6, 0, 1)
                + 0.1 * P.fbm(p * 0.5, 3, seed)[:, None],
                0,
                1,
            ),
        ),
    ]
    canopy = v.color("umbrella", [0.9, 0.2, 0.2], 0.6)
    for k in range(v.integer("umbrellas", 4, 1, 7)):  # umbrellas and rocks
        x, y = rng.uniform(-14, -5), rng.uniform(-12, 12)
        parts.append(
            Part(P.cylinder((x, y, sand(np.array([x]), np.array([y]))[0] - 0.2), 0.04, 2.2), P.solid([0.9, 0.9, 0.9]))
        )
        cone = o3d.geometry.TriangleMesh.create_cone(1.2, 0.5, 24).translate(
            (x, y, sand(np.array([x]), np.array([y]))[0] + 1.9)
        )
        parts.append(Part(cone, P.stripes(canopy, [0.95, 0.95, 0.9], 0.5, axis=2, seed=seed + k)))
    rock = v.color("rock", [0.35, 0.33, 0.3], 0.3)
    for k in range(v.integer("rocks", 6, 2, 10)):
        x, y = rng.uniform(6, 25), rng.uniform(-30, 30)
        parts.append(Part(P.sphere((x, y, -EYE_HEIGHT - 0.5), rng.uniform(0.8, 2.0)), P.noisy(rock, 0.3, 2, seed + k)))
    return _outdoor(parts, seed, v)


def city_plaza(seed: int, v: Draws) -> SyntheticWorld:
    seed = _texture_seed(seed, v)
    rng = np.random.default_rng(seed)
    ground = P.quad((-400, -400, -EYE_HEIGHT), (800, 0, 0), (0, 800, 0))
    parts = [
        Part(
            ground,
            P.tiles(
                v.color("paving", [0.62, 0.58, 0.52], 0.2),
                [0.35, 0.33, 0.3],
                v.uniform("paving_tile_m", 0.6, 0.4, 1.0),
                0.04,
                seed,
            ),
        )
    ]
    # the fountain, at a drawn distance and bearing from the viewer
    dist, bearing = (
        v.uniform("fountain_distance_m", 9.0, 8.0, 14.0),
        v.uniform("fountain_bearing_rad", 0.0, -np.pi, np.pi),
    )
    fx, fy = dist * np.cos(bearing), dist * np.sin(bearing)
    stone = P.noisy(v.color("stone", [0.75, 0.72, 0.66], 0.15), 0.15, 3, seed + 1)
    parts += [
        Part(P.cylinder((fx, fy, -EYE_HEIGHT), 4.0, 0.6), stone),
        Part(
            P.cylinder((fx, fy, -EYE_HEIGHT + 0.5), 3.7, 0.05),
            P.noisy(v.color("fountain_water", [0.3, 0.55, 0.7], 0.3), 0.2, 2, seed),
        ),
        Part(P.cylinder((fx, fy, -EYE_HEIGHT), 0.5, 2.2), stone),
        Part(P.cylinder((fx, fy, 0.5), 1.5, 0.25), stone),
        Part(P.sphere((fx, fy, 1.4), 0.6), P.noisy([0.75, 0.85, 0.95], 0.3, 5, seed + 2)),
    ]
    bench_r, lamp_r = v.uniform("bench_ring_m", 8.0, 6.5, 9.0), v.uniform("lamp_ring_m", 11.0, 9.5, 13.0)
    glow = v.color("lamp_glow", [1.0, 0.95, 0.8], 0.2)
    for k in range(8):  # stone benches in a ring, street lamps between them
        a = 2 * np.pi * (k + 0.5) / 8
        bx, by = fx + bench_r * np.cos(a), fy + bench_r * np.sin(a)
        parts.append(Part(P.box((bx, by, -EYE_HEIGHT + 0.23), (0.6, 2.0, 0.45), yaw=a), stone))
        lx, ly = fx + lamp_r * np.cos(a + np.pi / 8), fy + lamp_r * np.sin(a + np.pi / 8)
        parts.append(Part(P.cylinder((lx, ly, -EYE_HEIGHT), 0.08, 4.0), P.solid([0.15, 0.15, 0.17])))
        parts.append(Part(P.sphere((lx, ly, -EYE_HEIGHT + 4.2), 0.3), P.solid(glow), emissive=True))
    n_buildings = v.integer("buildings", 18, 12, 26)
    near, low, high = (
        v.uniform("buildings_near_m", 45.0, 35.0, 60.0),
        v.uniform("storeys_low_m", 12.0, 6.0, 20.0),
        v.uniform("storeys_high_m", 40.0, 25.0, 80.0),
    )
    windows = v.color("windows", [0.3, 0.4, 0.5], 0.3)
    for k in range(n_buildings):  # buildings around the open square
        a = 2 * np.pi * k / n_buildings + rng.uniform(-0.05, 0.05)
        r = rng.uniform(near, near + 15.0)
        hgt = rng.uniform(low, high)
        wall = rng.uniform(0.45, 0.85, 3)
        parts.append(
            Part(
                P.box((r * np.cos(a), r * np.sin(a), -EYE_HEIGHT + hgt / 2), (14, 14, hgt), yaw=a),
                P.facade(wall, windows, seed=seed + k),
            )
        )
    n_trees, tree_r = v.integer("trees", 6, 3, 9), v.uniform("tree_ring_m", 22.0, 16.0, 30.0)
    bark, leaves = v.color("bark", [0.35, 0.25, 0.15], 0.2), v.color("leaves", [0.2, 0.45, 0.15], 0.3)
    tree_angle = v.uniform("tree_angle_rad", 0.3, 0.0, 2 * np.pi)
    for k in range(n_trees):  # trees
        a = 2 * np.pi * k / n_trees + tree_angle
        tx, ty = tree_r * np.cos(a), tree_r * np.sin(a)
        parts.append(Part(P.cylinder((tx, ty, -EYE_HEIGHT), 0.25, 2.5), P.wood(bark, seed=seed, axis=2)))
        parts.append(Part(P.sphere((tx, ty, 2.0), 2.2), P.noisy(leaves, 0.35, 3, seed + k)))
    return _outdoor(parts, seed, v)


# ---------------------------------------------------------------- registry
_BUILDERS = {
    "bedroom": bedroom,
    "bathroom": bathroom,
    "library": library,
    "exhibition-hall": exhibition_hall,
    "mountain": mountain,
    "grassland": grassland,
    "beach": beach,
    "city-plaza": city_plaza,
}

MIN_FREE_RADIUS = 0.5  # metres: a variant drawn with less free space around the eye is drawn again
MAX_DRAWS = 20

_WORLDS: dict[tuple[str, int], SyntheticWorld] = {}


def _draw_variant(base: str, k: int, seed: int) -> SyntheticWorld:
    """Variant ``k`` of scene ``base``: its parameters drawn from ``variant_rng(base, k)``; a draw whose free-space
    radius is below MIN_FREE_RADIUS (furniture at the eye) is discarded and the next one, from the same
    Generator, taken."""
    rng = variant_rng(base, k)
    for redraws in range(MAX_DRAWS):
        v = Draws(rng)
        w = _BUILDERS[base](seed, v)
        if w.free_space_radius() >= MIN_FREE_RADIUS:
            w.variant, w.params, w.redraws = k, v.params, redraws
            return w
    raise RuntimeError(f"{base}@{k}: no draw of {MAX_DRAWS} leaves {MIN_FREE_RADIUS} m free around the eye")


def world(name: str, seed: int = SCENE_SEED) -> SyntheticWorld:
    """The (cached) world of a synthetic scene: a base name (``bedroom``) or a variant (``bedroom@3``)."""
    key = (name, seed)
    if key not in _WORLDS:
        base, k = split_variant(name)
        if k is None:
            v = Draws()
            _WORLDS[key] = _BUILDERS[base](seed, v)
            _WORLDS[key].params = v.params
        else:
            _WORLDS[key] = _draw_variant(base, k, seed)
    return _WORLDS[key]


def build_scene(name: str, width: int | None = None, seed: int = SCENE_SEED) -> Scene:
    """Render a synthetic scene (or a variant, ``bedroom@3``) at ``width`` (default 1024) from the origin."""
    w = world(name, seed)
    base, k = split_variant(name)
    width = DEFAULT_WIDTH if width is None else width
    erp = w.render_erp(width // 2)
    return Scene(
        name=name,
        kind="synthetic",
        description=SYNTHETIC_SCENES[base] + ("" if k is None else f"; variant {k}"),
        rgb=erp.rgb,
        distance=erp.distance,
        sky=erp.sky,
        distance_kind="truth",
        world=w,
        meta={
            "seed": seed,
            "parts": len(w.parts),
            "outdoor": w.outdoor,
            "eye_height_m": EYE_HEIGHT,
            "variant": k,
            **({} if k is None else {"redraws": w.redraws}),
            "params": w.params,
        },
    )
