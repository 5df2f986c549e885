"""CPU ray-cast rendering of a pile: RGB, z-depth, instance ids (open3d RaycastingScene).

Per view and pixel (u, v) one ray leaves the camera centre along
``R_world_camera @ [(u - cx) / fx, (v - cy) / fy, 1]``; because that direction has unit
z in the camera frame, the hit distance ``t_hit`` *is* the z-depth (along the optical
axis, not the ray length). Pixel centres sit at integer (u, v) (docs/conventions.md).

Colour: per-face albedo (objects, tray) or a procedural table pattern, Lambertian
shading with a hemispherical ambient term and one directional light, and a hard
shadow from one shadow ray per pixel toward the light. Instance id: the geometry
id of the hit mapped to the object index, -1 for table, tray and misses.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from clutt3r_core.scene import Camera
from clutt3r_core.synth.objects import SynthObject
from clutt3r_core.synth.physics import TraySpec, tray_boxes

__all__ = ["Lighting", "TableStyle", "TABLE_STYLES", "RenderedView", "PileGeometry", "build_geometry",
           "render_view", "amodal_areas", "look_at_camera"]


@dataclass(frozen=True)
class Lighting:
    """One directional light plus ambient (ours).

    Attributes:
        direction: (3,) unit vector from the scene *toward* the light, world frame.
        ambient: ambient intensity (sky term, scaled by 0.75 + 0.25 n_z).
        diffuse: Lambertian intensity of the light.
    """

    direction: tuple[float, float, float] = (0.3, 0.2, 0.93)
    ambient: float = 0.38
    diffuse: float = 0.72


@dataclass(frozen=True)
class TableStyle:
    """Procedural table appearance: a base colour modulated by wood-like grain and fine speckle.

    Attributes:
        name: style name.
        color: (r, g, b) base colour.
        grain: relative amplitude of the grain stripes.
        grain_period: stripe period, metres.
        speckle: relative amplitude of the fine speckle (about 4 mm cells).
    """

    name: str
    color: tuple[int, int, int]
    grain: float = 0.12
    grain_period: float = 0.045
    speckle: float = 0.06


TABLE_STYLES: tuple[TableStyle, ...] = (
    TableStyle("oak", (176, 138, 96), 0.10, 0.045, 0.05),
    TableStyle("grey laminate", (150, 150, 146), 0.04, 0.080, 0.08),
    TableStyle("white melamine", (214, 212, 204), 0.03, 0.120, 0.05),
    TableStyle("walnut", (112, 80, 58), 0.12, 0.035, 0.05),
)

_SKY = np.array([196.0, 202.0, 210.0])
_TABLE_HALF = 3.0  # metres: the table quad is 6 x 6 m so every ray of a tabletop camera hits it


@dataclass(frozen=True, eq=False)
class RenderedView:
    """One rendered view.

    Attributes:
        rgb: (H, W, 3) uint8.
        depth: (H, W) float32 clean z-depth in metres, NaN where the ray hits nothing.
        instance: (H, W) int32 object index, -1 for table, tray and misses.
        cos_incidence: (H, W) float32 |cos| of the angle between ray and surface normal
            (1 = head-on, 0 = grazing), 0 on misses; drives sensor dropout.
    """

    rgb: np.ndarray
    depth: np.ndarray
    instance: np.ndarray
    cos_incidence: np.ndarray


class PileGeometry:
    """Ray-casting scene of posed objects, table and tray (built once per pile state).

    Internal arrays concatenate every geometry so shading is vectorised over pixels:
    ``face_offset[g] + primitive_id`` indexes ``faces`` / ``face_colors``.
    """

    def __init__(self) -> None:
        import open3d as o3d

        self.o3d = o3d
        self.scene = o3d.t.geometry.RaycastingScene()
        self.vertices: list[np.ndarray] = []
        self.normals: list[np.ndarray] = []
        self.faces: list[np.ndarray] = []
        self.colors: list[np.ndarray] = []
        self.owner: list[int] = []  # object index per geometry id, -1 background
        self.is_table: list[bool] = []
        self.face_offset: list[int] = []
        self._nv = 0
        self._nf = 0
        self.object_meshes: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        self._solo: dict[int, object] = {}  # object id -> RaycastingScene of that object alone

    def solo(self, oid: int):
        """Ray-casting scene holding object ``oid`` alone (built on first use)."""
        if oid not in self._solo:
            v, f = self.object_meshes[oid]
            s = self.o3d.t.geometry.RaycastingScene()
            s.add_triangles(v.astype(np.float32), f.astype(np.uint32))
            self._solo[oid] = s
        return self._solo[oid]

    def add(self, v: np.ndarray, f: np.ndarray, n: np.ndarray, colors: np.ndarray, owner: int,
            table: bool = False) -> None:
        gid = self.scene.add_triangles(v.astype(np.float32), f.astype(np.uint32))
        if gid != len(self.owner):
            raise RuntimeError("open3d geometry ids are expected to be consecutive")
        self.vertices.append(v)
        self.normals.append(n)
        self.faces.append(f.astype(np.int64) + self._nv)
        self.colors.append(colors)
        self.owner.append(owner)
        self.is_table.append(table)
        self.face_offset.append(self._nf)
        self._nv += len(v)
        self._nf += len(f)

    def finish(self) -> None:
        self.V = np.concatenate(self.vertices)
        self.N = np.concatenate(self.normals)
        self.F = np.concatenate(self.faces)
        self.C = np.concatenate(self.colors).astype(np.float64)
        self.owner_arr = np.asarray(self.owner + [-1], np.int32)  # last entry: miss
        self.table_arr = np.asarray(self.is_table + [False])
        self.offset_arr = np.asarray(self.face_offset + [0], np.int64)


def _box_mesh(centre: np.ndarray, half: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Axis-aligned box as 12 triangles with per-vertex (flat, duplicated) normals."""
    import trimesh

    b = trimesh.creation.box(extents=2 * half)
    b.apply_translation(centre)
    # unshare vertices so normals are flat per face
    v = b.vertices[b.faces].reshape(-1, 3)
    f = np.arange(len(v)).reshape(-1, 3)
    n = np.repeat(b.face_normals, 3, axis=0)
    return v, f, n


def build_geometry(
    objects: Sequence[SynthObject],
    poses: np.ndarray,
    object_ids: Sequence[int],
    *,
    centre: np.ndarray = np.zeros(3),
    tray: TraySpec | None = None,
) -> PileGeometry:
    """Ray-casting scene of ``objects[i]`` at ``poses[i]`` carrying instance id ``object_ids[i]``."""
    g = PileGeometry()
    c = np.array([centre[0], centre[1], 0.0])
    h = _TABLE_HALF
    tv = np.array([[-h, -h, 0], [h, -h, 0], [h, h, 0], [-h, h, 0]], np.float64) + c
    g.add(tv, np.array([[0, 1, 2], [0, 2, 3]]), np.tile([0.0, 0.0, 1.0], (4, 1)), np.zeros((2, 3)), -1, table=True)
    if tray is not None:
        for bc, he in tray_boxes(tray):
            v, f, n = _box_mesh(bc + c, he)
            g.add(v, f, n, np.tile(np.asarray(tray.color, np.float64), (len(f), 1)), -1)
    for obj, T, oid in zip(objects, poses, object_ids):
        R, t = T[:3, :3], T[:3, 3]
        v = obj.vertices @ R.T + t
        g.add(v, obj.faces, obj.vertex_normals @ R.T, obj.face_colors, int(oid))
        g.object_meshes[int(oid)] = (v, obj.faces)
    g.finish()
    return g


def look_at_camera(eye: np.ndarray, target: np.ndarray, K: np.ndarray, width: int, height: int) -> Camera:
    """OpenCV camera at ``eye`` looking at ``target`` with image rows pointing down (world -z)."""
    z = np.asarray(target, np.float64) - np.asarray(eye, np.float64)
    z /= np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    T = np.eye(4)
    T[:3, 0], T[:3, 1], T[:3, 2], T[:3, 3] = x, y, z, eye
    return Camera(K, width, height, T)


def _rays(camera: Camera, us: np.ndarray, vs: np.ndarray) -> np.ndarray:
    """(N, 6) float32 rays (origin, direction with unit camera-z) through pixels (us, vs)."""
    d = np.stack([(us - camera.cx) / camera.fx, (vs - camera.cy) / camera.fy, np.ones_like(us, np.float64)], -1)
    R = camera.T_world_camera[:3, :3]
    dw = d @ R.T
    o = np.broadcast_to(camera.T_world_camera[:3, 3], dw.shape)
    return np.concatenate([o, dw], axis=1).astype(np.float32)


def _table_albedo(p: np.ndarray, style: TableStyle) -> np.ndarray:
    """(N, 3) albedo of table points (N, 3) world: grain stripes along x, warped, plus speckle."""
    x, y = p[:, 0], p[:, 1]
    warp = 0.35 * np.sin(x / 0.11) + 0.15 * np.sin(x / 0.043 + 1.3)
    grain = np.sin(2 * np.pi * (y / style.grain_period + warp))
    # speckle: hash of a 4 mm cell index, deterministic and view-independent
    ix = np.floor(x / 0.004).astype(np.int64)
    iy = np.floor(y / 0.004).astype(np.int64)
    hsh = (ix * 73856093) ^ (iy * 19349663)
    speck = ((hsh % 1009) / 1008.0) * 2 - 1
    f = 1.0 + style.grain * grain + style.speckle * speck
    return np.asarray(style.color, np.float64)[None, :] * f[:, None]


def render_view(
    geom: PileGeometry,
    camera: Camera,
    *,
    lighting: Lighting = Lighting(),
    table: TableStyle = TABLE_STYLES[0],
) -> RenderedView:
    """Render one view of ``geom`` with ``camera`` (see module docstring)."""
    o3d = geom.o3d
    H, W = camera.height, camera.width
    vs, us = np.mgrid[0:H, 0:W]
    rays = _rays(camera, us.reshape(-1).astype(np.float64), vs.reshape(-1).astype(np.float64))
    ans = geom.scene.cast_rays(o3d.core.Tensor(rays))
    t = ans["t_hit"].numpy().astype(np.float64)
    hit = np.isfinite(t)
    gid = ans["geometry_ids"].numpy().astype(np.int64)
    gid[~hit] = len(geom.owner)  # the "miss" slot of the lookup arrays
    prim = ans["primitive_ids"].numpy().astype(np.int64)
    uv = ans["primitive_uvs"].numpy().astype(np.float64)

    inst = geom.owner_arr[gid]
    depth = np.where(hit, t, np.nan)

    hi = np.flatnonzero(hit)
    face = geom.offset_arr[gid[hi]] + prim[hi]
    tri = geom.F[face]  # (n, 3) global vertex ids
    w = np.stack([1 - uv[hi, 0] - uv[hi, 1], uv[hi, 0], uv[hi, 1]], axis=1)
    n = np.einsum("nk,nkd->nd", w, geom.N[tri])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    dirs = rays[hi, 3:].astype(np.float64)
    dn = dirs / np.linalg.norm(dirs, axis=1, keepdims=True)
    facing = np.sum(n * dn, axis=1)
    n[facing > 0] *= -1  # shade the side the camera sees (open meshes show their inside)
    cos_inc = np.abs(facing)

    p = rays[hi, :3].astype(np.float64) + dirs * t[hi, None]
    albedo = geom.C[face]
    on_table = geom.table_arr[gid[hi]]
    if on_table.any():
        albedo[on_table] = _table_albedo(p[on_table], table)

    L = np.asarray(lighting.direction, np.float64)
    L = L / np.linalg.norm(L)
    lam = np.clip(n @ L, 0.0, None)
    srays = np.concatenate([p + 1e-3 * n, np.broadcast_to(L, p.shape)], axis=1).astype(np.float32)
    lit_mask = lam > 0
    shadow = np.zeros(len(hi), bool)
    if lit_mask.any():
        shadow[lit_mask] = geom.scene.test_occlusions(o3d.core.Tensor(srays[lit_mask])).numpy()
    shade = lighting.ambient * (0.75 + 0.25 * n[:, 2]) + lighting.diffuse * lam * (~shadow)

    rgb = np.tile(_SKY, (H * W, 1))
    rgb[hi] = albedo * shade[:, None]
    cos_full = np.zeros(H * W)
    cos_full[hi] = cos_inc
    return RenderedView(
        rgb=np.clip(np.round(rgb), 0, 255).astype(np.uint8).reshape(H, W, 3),
        depth=depth.astype(np.float32).reshape(H, W),
        instance=inst.astype(np.int32).reshape(H, W),
        cos_incidence=cos_full.astype(np.float32).reshape(H, W),
    )


def amodal_areas(geom: PileGeometry, camera: Camera) -> dict[int, int]:
    """Pixel count of every object's full silhouette (as if alone), for occlusion ratios.

    Rays are cast only inside the object's projected bounding box, against a scene that
    holds that object alone, so the sampling equals that of ``render_view``.
    """
    o3d = geom.o3d
    out: dict[int, int] = {}
    H, W = camera.height, camera.width
    for oid, (v, f) in geom.object_meshes.items():
        uvp, z = camera.project(v)
        if not np.any(z > 0):
            out[oid] = 0
            continue
        uvp = uvp[z > 0]
        u0, v0 = np.floor(uvp.min(0)).astype(int)
        u1, v1 = np.ceil(uvp.max(0)).astype(int)
        u0, v0, u1, v1 = max(u0, 0), max(v0, 0), min(u1, W - 1), min(v1, H - 1)
        if u1 < u0 or v1 < v0:
            out[oid] = 0
            continue
        s = geom.solo(oid)
        vv, uu = np.mgrid[v0 : v1 + 1, u0 : u1 + 1]
        rays = _rays(camera, uu.reshape(-1).astype(np.float64), vv.reshape(-1).astype(np.float64))
        out[oid] = int(s.test_occlusions(o3d.core.Tensor(rays)).numpy().sum())
    return out
