"""Synthetic cluttered-tabletop scenes: the offline default for the demo, tests and benchmarks.

Pipeline (every random draw comes from a generator seeded by ``(seed, stream, index)``,
so a seed gives byte-identical arrays):

1. pick ``n_objects`` YCB models from the registry (``objects.py``);
2. drop them onto the table or into a tray with pybullet and let them settle; objects
   that fall off are replaced and the pile is re-dropped (``physics.py``);
3. place ``views`` cameras on a robot-reachable arc around the pile and ray-cast RGB,
   z-depth and instance ids (``render.py``); optional RealSense-like depth noise
   (``sensor.py``); Grounded-SAM-like noisy mask candidates per view (``masks.py``);
4. ground truth: objects (category, model, pose, colour), per-view instance maps,
   labelled points back-projected from the clean depth of the initial views (voxel
   subsampled), and the occlusion ratio of every object in every view;
5. optionally (``prepost``) remove one object (grasped), push a neighbour by a known
   planar motion, let it re-settle, and render one post-interaction view.

``generate_scene(cfg) -> Scene``; ``generate(cfg) -> SynthResult`` also returns the
generation record (``SynthInfo``: occlusion, interaction, mask provenance, timings);
``write_synth_scene(scene, out_dir)`` writes the sample layout plus ``gt/synth_info.json``,
``gt/interaction.json`` (prepost) and ``contact_sheet.png``.
"""

from __future__ import annotations

import json
import time
import weakref
from pathlib import Path

import numpy as np

from clutt3r_core.errors import SceneError
from clutt3r_core.scene import Camera, GroundTruth, ObjectInfo, Scene, View
from clutt3r_core.synth.masks import mask_noise_preset, noisy_masks
from clutt3r_core.synth.objects import SynthObject, load_object, registry_keys
from clutt3r_core.synth.physics import TraySpec, pose_matrix, resettle_object, settle_pile
from clutt3r_core.synth.render import (
    TABLE_STYLES,
    Lighting,
    PileGeometry,
    RenderedView,
    amodal_areas,
    build_geometry,
    look_at_camera,
    render_view,
)
from clutt3r_core.synth.sensor import apply_depth_noise, depth_noise_preset

__all__ = ["Difficulty", "DifficultyPreset", "DIFFICULTY_PRESETS", "SynthConfig", "InteractionInfo", "SynthInfo",
           "SynthResult", "generate", "generate_scene", "synth_info", "write_synth_scene", "load_synth_info"]

from clutt3r_core.synth.types import (  # noqa: F401  (re-exported)
    DIFFICULTY_PRESETS,
    Difficulty,
    DifficultyPreset,
    InteractionInfo,
    SynthConfig,
    SynthInfo,
    SynthResult,
)

# Random streams: (seed, stream, index) seeds one numpy Generator per purpose and item.
_S_OBJECTS, _S_PHYSICS, _S_CAMERAS, _S_LOOK, _S_MASKS, _S_DEPTH, _S_INTERACT, _S_POSTCAM = range(8)
_GT_VOXEL = 0.0025  # metres: voxel of the labelled ground-truth points (2.5 mm)
_GT_MARGIN = 0.12  # metres: background points farther than this outside the pile area are dropped
_MAX_DROPS = 4  # pile attempts before accepting fewer objects than asked


def _rng(seed: int, stream: int, index: int = 0) -> np.random.Generator:
    return np.random.default_rng([int(seed), int(stream), int(index)])


_INFO: "weakref.WeakKeyDictionary[Scene, SynthInfo]" = weakref.WeakKeyDictionary()


def synth_info(scene: Scene) -> SynthInfo | None:
    """The generation record of a scene made by ``generate_scene`` in this process, else None."""
    return _INFO.get(scene)


# ---------------------------------------------------------------- stages


def _choose_objects(cfg: SynthConfig) -> list[str]:
    if cfg.objects is not None:
        return list(cfg.objects)
    keys = registry_keys()
    n = cfg.object_count
    rng = _rng(cfg.seed, _S_OBJECTS)
    idx = rng.choice(len(keys), size=n, replace=n > len(keys))
    return [keys[i] for i in idx]


def _pile(cfg: SynthConfig, keys: list[str], centre: np.ndarray, tray: TraySpec | None):
    """Settle; replace fallen objects by fresh draws and re-drop, keep the best attempt."""
    best = None
    pool_rng = _rng(cfg.seed, _S_OBJECTS, 1)
    all_keys = registry_keys()
    for attempt in range(_MAX_DROPS):
        objs = [load_object(k) for k in keys]
        pile = settle_pile(objs, _rng(cfg.seed, _S_PHYSICS, attempt), centre=centre,
                           pile_radius=cfg.radius, tray=tray)
        kept = [k for k, ok in zip(keys, pile.kept) if ok]
        cand = (len(kept), attempt, keys, pile)
        if best is None or cand[0] > best[0]:
            best = cand
        if len(kept) == len(keys):
            break
        if cfg.objects is None:  # replace the fallen ones with unused models
            unused = [k for k in all_keys if k not in kept] or list(all_keys)
            extra = [unused[i] for i in pool_rng.choice(len(unused), len(keys) - len(kept), replace=False)] \
                if len(unused) >= len(keys) - len(kept) else list(pool_rng.choice(unused, len(keys) - len(kept)))
            keys = kept + extra
    _, _, keys, pile = best
    sel = np.flatnonzero(pile.kept)
    return [keys[i] for i in sel], pile.poses[sel], pile


def _cameras(cfg: SynthConfig, rng: np.random.Generator, target: np.ndarray, n: int,
             obj_points: np.ndarray, az0: float) -> list[Camera]:
    """``n`` cameras on an arc around ``target``; re-draw a pose (up to 20 times) until every
    object point projects inside the image with a 2 % margin."""
    K, W, H = cfg.K, cfg.width, cfg.height
    span = np.radians(cfg.azimuth_span_deg)
    cams = []
    for i in range(n):
        best = None
        for _ in range(20):
            az = az0 - span / 2 + span * (i + 0.5 + rng.uniform(-0.3, 0.3)) / n
            el = np.radians(rng.uniform(*cfg.elevation_deg))
            d = rng.uniform(*cfg.distance)
            eye = target + d * np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
            look = target + np.append(rng.normal(0, 0.01, 2), 0.0)
            cam = look_at_camera(eye, look, K, W, H)
            uv, z = cam.project(obj_points)
            m = 0.02
            ok = (z > 0) & (uv[:, 0] >= m * W) & (uv[:, 0] <= (1 - m) * W) & (uv[:, 1] >= m * H) & (uv[:, 1] <= (1 - m) * H)
            frac = ok.mean()
            if best is None or frac > best[0]:
                best = (frac, cam)
            if frac == 1.0:
                break
        cams.append(best[1])
    return cams


def _object_points(objs: list[SynthObject], poses: np.ndarray, per: int = 64) -> np.ndarray:
    pts = []
    for o, T in zip(objs, poses):
        v = o.vertices[:: max(1, len(o.vertices) // per)]
        pts.append(v @ T[:3, :3].T + T[:3, 3])
    return np.concatenate(pts) if pts else np.zeros((0, 3))


def _view_from_render(cfg: SynthConfig, frame: int, cam: Camera, r: RenderedView):
    dcfg = depth_noise_preset(cfg.depth_noise)
    depth = apply_depth_noise(r.depth, r.cos_incidence, cam.fx, dcfg, _rng(cfg.seed, _S_DEPTH, frame))
    nm = noisy_masks(r.instance, mask_noise_preset(cfg.mask_noise), _rng(cfg.seed, _S_MASKS, frame),
                     valid=np.isfinite(r.depth))
    view = View(frame=frame, rgb=r.rgb, camera=cam, depth=depth, masks=nm.candidates,
                name=f"image_{frame:06d}.png")
    return view, nm


def _voxel_subsample(p: np.ndarray, lab: np.ndarray, voxel: float) -> tuple[np.ndarray, np.ndarray]:
    """Keep the first point (in input order) of every ``voxel`` cell: deterministic."""
    if len(p) == 0:
        return p, lab
    q = np.floor(p / voxel).astype(np.int64)
    q -= q.min(0)
    dims = q.max(0) + 1
    key = (q[:, 0] * dims[1] + q[:, 1]) * dims[2] + q[:, 2]
    _, first = np.unique(key, return_index=True)
    first.sort()
    return p[first], lab[first]


def _supports(geom: PileGeometry, objs: list[SynthObject], poses: np.ndarray) -> np.ndarray:
    """(K, K) bool, [a, b] = b rests on a (b touches a within 3 mm and b's centre is higher)."""
    import open3d as o3d

    K = len(objs)
    sup = np.zeros((K, K), bool)
    pts = []
    for o, T in zip(objs, poses):
        v = o.vertices[:: max(1, len(o.vertices) // 400)]
        pts.append((v @ T[:3, :3].T + T[:3, 3]).astype(np.float32))
    for a in range(K):
        scene = geom.solo(a)
        for b in range(K):
            if a == b or poses[b][2, 3] <= poses[a][2, 3]:
                continue
            d = scene.compute_distance(o3d.core.Tensor(pts[b])).numpy()
            sup[a, b] = bool(d.min() < 0.003)
    return sup


def _interaction(cfg: SynthConfig, geom: PileGeometry, objs: list[SynthObject], poses: np.ndarray,
                 centre: np.ndarray, tray: TraySpec | None, post_frame: int):
    """Choose the grasped and the pushed object, push and re-settle. Returns (InteractionInfo, post poses)."""
    K = len(objs)
    if K < 2:
        raise SceneError("a pre/post-interaction pair needs at least 2 objects in the pile")
    rng = _rng(cfg.seed, _S_INTERACT)
    sup = _supports(geom, objs, poses)
    free = ~sup.any(axis=1)  # objects with nothing resting on them can be taken away or pushed
    xy = poses[:, :2, 3]
    dist = np.linalg.norm(xy[:, None] - xy[None], axis=2)
    np.fill_diagonal(dist, np.inf)
    cand = [a for a in range(K) if free[a] and np.isfinite(dist[a][free]).any()]
    if not cand:
        cand = list(range(K))
    removed = int(cand[int(rng.integers(len(cand)))])
    others = np.where(free, dist[removed], np.inf)
    others[removed] = np.inf
    if not np.isfinite(others).any():
        others = dist[removed].copy()
    displaced = int(np.argmin(others))

    p = poses[displaced][:3, 3]
    out = p[:2] - centre[:2]
    ang = np.arctan2(out[1], out[0]) if np.linalg.norm(out) > 1e-3 else rng.uniform(0, 2 * np.pi)
    ang += rng.uniform(-0.7, 0.7)
    shift = rng.uniform(0.05, 0.09) * np.array([np.cos(ang), np.sin(ang)])
    target = p[:2] + shift
    if tray is not None:  # stay inside the walls
        r = 0.6 * objs[displaced].radius
        lim = np.array([tray.half_x - r, tray.half_y - r])
        target = centre[:2] + np.clip(target - centre[:2], -np.maximum(lim, 0), np.maximum(lim, 0))
    yaw = rng.choice([-1.0, 1.0]) * rng.uniform(np.radians(20), np.radians(60))
    c, s = np.cos(yaw), np.sin(yaw)
    Rz = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])
    T_move = pose_matrix(np.eye(3), np.array([target[0], target[1], p[2]])) @ pose_matrix(Rz, np.zeros(3)) \
        @ pose_matrix(np.eye(3), -p)
    present = np.ones(K, bool)
    present[removed] = False
    T_post = resettle_object(objs, poses, present, displaced, T_move, centre=centre, tray=tray)
    T_new_old = T_post @ np.linalg.inv(poses[displaced])
    post_poses = poses.copy()
    post_poses[displaced] = T_post
    info = InteractionInfo(post_frame, removed, displaced, T_new_old, T_post)
    return info, post_poses, present


# ---------------------------------------------------------------- API


def generate(cfg: SynthConfig = SynthConfig(), *, progress: bool = True) -> SynthResult:
    """Generate one scene and its generation record (see the module docstring)."""
    from tqdm.auto import tqdm

    t_start = time.perf_counter()
    secs: dict[str, float] = {}
    n_steps = 4 + cfg.views + (2 if cfg.prepost else 0)
    bar = tqdm(total=n_steps, desc=cfg.scene_name, disable=None if progress else True, leave=False)
    try:
        look = _rng(cfg.seed, _S_LOOK)
        centre = np.array([look.uniform(-0.05, 0.05), look.uniform(-0.05, 0.05), 0.0])
        tray = TraySpec(half_x=cfg.radius + 0.11, half_y=cfg.radius + 0.07) if cfg.use_tray else None
        floor = tray.floor_thickness if tray is not None else 0.0
        light_az = look.uniform(0, 2 * np.pi)
        light_el = np.radians(look.uniform(45, 75))
        lighting = Lighting(direction=(float(np.cos(light_el) * np.cos(light_az)),
                                       float(np.cos(light_el) * np.sin(light_az)), float(np.sin(light_el))))
        table = TABLE_STYLES[int(look.integers(len(TABLE_STYLES)))]
        az0 = look.uniform(0, 2 * np.pi)

        bar.set_postfix_str("physics")
        t = time.perf_counter()
        keys, poses, _ = _pile(cfg, _choose_objects(cfg), centre, tray)
        if not keys:
            raise SceneError(f"{cfg.scene_name}: every object fell off the table; try another seed")
        objs = [load_object(k) for k in keys]
        secs["physics"] = time.perf_counter() - t
        bar.update(1)

        t = time.perf_counter()
        geom = build_geometry(objs, poses, range(len(objs)), centre=centre, tray=tray)
        obj_pts = _object_points(objs, poses)
        top = float(obj_pts[:, 2].max()) if len(obj_pts) else floor
        target = np.array([centre[0], centre[1], floor + 0.4 * (top - floor)])
        cams = _cameras(cfg, _rng(cfg.seed, _S_CAMERAS), target, cfg.views, obj_pts, az0)
        bar.update(1)

        views, renders, kinds, sources = [], [], {}, {}
        occ = np.full((len(objs), cfg.views), np.nan)
        t_masks = 0.0
        for i, cam in enumerate(cams):
            bar.set_postfix_str(f"view {i}")
            r = render_view(geom, cam, lighting=lighting, table=table)
            am = amodal_areas(geom, cam)
            vis = np.bincount(r.instance[r.instance >= 0], minlength=len(objs))
            for k in range(len(objs)):
                if am[k] > 0:
                    occ[k, i] = float(np.clip(1.0 - vis[k] / am[k], 0.0, 1.0))
            tm = time.perf_counter()
            v, nm = _view_from_render(cfg, i, cam, r)
            t_masks += time.perf_counter() - tm
            views.append(v)
            renders.append(r)
            kinds[i], sources[i] = nm.kinds, nm.sources
            bar.update(1)
        secs["masks"] = t_masks
        secs["render"] = time.perf_counter() - t - t_masks

        # labelled points from the clean depth of the initial views
        bar.set_postfix_str("points")
        t = time.perf_counter()
        P, L = [], []
        for cam, r in zip(cams, renders):
            p, pix = cam.backproject(r.depth)
            P.append(p)
            L.append(r.instance.reshape(-1)[pix])
        P, L = np.concatenate(P), np.concatenate(L).astype(np.int32)
        reach = (tray.half_x + tray.wall_thickness if tray is not None else cfg.radius + 0.08) + _GT_MARGIN
        keep = (L >= 0) | (np.linalg.norm(P[:, :2] - centre[:2], axis=1) <= reach)
        P, L = _voxel_subsample(P[keep], L[keep], _GT_VOXEL)
        secs["points"] = time.perf_counter() - t
        bar.update(1)

        instance_maps = {i: r.instance for i, r in enumerate(renders)}
        interaction = None
        post_idx: tuple[int, ...] = ()
        if cfg.prepost:
            bar.set_postfix_str("interaction")
            t = time.perf_counter()
            post_frame = cfg.views
            interaction, post_poses, present = _interaction(cfg, geom, objs, poses, centre, tray, post_frame)
            bar.update(1)
            sel = np.flatnonzero(present)
            geom_post = build_geometry([objs[i] for i in sel], post_poses[sel], sel, centre=centre, tray=tray)
            post_pts = _object_points([objs[i] for i in sel], post_poses[sel])
            rng_pc = _rng(cfg.seed, _S_POSTCAM)
            cam = _cameras(cfg, rng_pc, target, 1, post_pts, rng_pc.uniform(0, 2 * np.pi))[0]
            r = render_view(geom_post, cam, lighting=lighting, table=table)
            v, nm = _view_from_render(cfg, post_frame, cam, r)
            views.append(v)
            kinds[post_frame], sources[post_frame] = nm.kinds, nm.sources
            instance_maps[post_frame] = r.instance
            post_idx = (len(views) - 1,)
            secs["prepost"] = time.perf_counter() - t
            bar.update(1)

        objects = tuple(
            ObjectInfo(id=k, category=o.spec.category, name=o.spec.key, T_world_object=poses[k], color=o.spec.color)
            for k, o in enumerate(objs)
        )
        gt = GroundTruth(objects, instance_maps, P.astype(np.float32), L)
        scene = Scene(views=tuple(views), initial=tuple(range(cfg.views)), post=post_idx, ground_truth=gt,
                      name=cfg.scene_name)
        finite = occ[np.isfinite(occ)]
        secs["total"] = time.perf_counter() - t_start
        info = SynthInfo(cfg, tuple(keys), tuple(range(cfg.views)), occ,
                         float(finite.mean()) if finite.size else float("nan"), centre, kinds, sources,
                         interaction, secs)
        bar.update(1)
    finally:
        bar.close()
    _INFO[scene] = info
    return SynthResult(scene, info)


def generate_scene(cfg: SynthConfig = SynthConfig(), *, progress: bool = True) -> Scene:
    """Generate one synthetic scene (``Scene`` with ground truth). Deterministic for ``cfg``.

    The generation record (occlusion, interaction, mask provenance) is available through
    ``synth_info(scene)`` and is written by ``write_synth_scene``.
    """
    return generate(cfg, progress=progress).scene


def _dump(path: Path, obj: object) -> None:
    from clutt3r_core.io.images import atomic_write_bytes

    atomic_write_bytes(path, (json.dumps(obj, indent=1) + "\n").encode())


def write_synth_scene(scene: Scene, out_dir: str | Path, *, info: SynthInfo | None = None,
                      contact_sheet: bool = True) -> Path:
    """Write a generated scene in the sample layout (``io.sample_layout.write_sample_layout``)
    plus ``gt/synth_info.json``, ``gt/interaction.json`` (pre/post scenes) and ``contact_sheet.png``.
    Returns the folder."""
    from clutt3r_core.io.sample_layout import write_sample_layout

    out = Path(out_dir)
    write_sample_layout(scene, out)
    info = info if info is not None else synth_info(scene)
    if info is not None:
        (out / "gt").mkdir(exist_ok=True)
        _dump(out / "gt" / "synth_info.json", info.to_json())
        if info.interaction is not None:
            _dump(out / "gt" / "interaction.json", info.interaction.to_json())
    if contact_sheet:
        from clutt3r_core.synth.contact_sheet import write_contact_sheet

        write_contact_sheet(scene, out / "contact_sheet.png", info=info)
    return out


def load_synth_info(root: str | Path) -> SynthInfo:
    """Read the generation record (``gt/synth_info.json`` and ``gt/interaction.json``) of a written scene."""
    from clutt3r_core.errors import SceneFileError

    root = Path(root)
    p = root / "gt" / "synth_info.json"
    if not p.is_file():
        raise SceneFileError(p, "not found: not a scene written by write_synth_scene")
    ip = root / "gt" / "interaction.json"
    try:
        meta = json.loads(p.read_text())
        inter = json.loads(ip.read_text()) if ip.is_file() else None
    except json.JSONDecodeError as e:
        raise SceneFileError(p, f"not valid JSON ({e.msg})") from None
    try:
        return SynthInfo.from_json(meta, inter)
    except (KeyError, TypeError, ValueError, SceneError) as e:
        raise SceneFileError(p, f"unreadable generation record: {e}") from None
