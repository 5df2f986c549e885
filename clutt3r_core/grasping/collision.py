"""Collision tests of the antipodal planner: distance grid, unseen space, palm and finger samples.

See ``clutt3r_core/grasping/antipodal.py`` (steps 3 and 4) for what each test proves.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from clutt3r_core.grasping import DepthView

__all__ = ["Grid", "unseen_occupied", "distance_grid", "palm_and_unseen"]


@dataclass(frozen=True, eq=False)
class Grid:
    origin: np.ndarray  # (3,) world position of cell (0, 0, 0)'s corner
    cell: float
    shape: tuple[int, int, int]

    def index(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(..., 3) world points -> (flat cell index (...,) int64, inside (...,) bool)."""
        ijk = np.floor((p - self.origin) / self.cell).astype(np.int64)
        s = np.asarray(self.shape)
        inside = np.all((ijk >= 0) & (ijk < s), axis=-1)
        ijk = np.clip(ijk, 0, s - 1)
        return (ijk[..., 0] * s[1] + ijk[..., 1]) * s[2] + ijk[..., 2], inside

    def centres(self) -> np.ndarray:
        axes = [self.origin[i] + self.cell * (np.arange(self.shape[i]) + 0.5) for i in range(3)]
        return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)


def unseen_occupied(points: np.ndarray, views: tuple[DepthView, ...], tolerance: float) -> np.ndarray:
    """(P, 3) world points -> (P,) bool: hidden behind the observed surface in every view that sees them.

    A view *sees* a point when it projects inside the image, in front of the camera, onto a
    valid depth pixel; it says *hidden* when the point is more than ``tolerance`` metres behind
    that depth. Occupied-unseen = seen by at least one view and hidden in all that see it.
    """
    p = np.asarray(points, np.float64).reshape(-1, 3)
    seen = np.zeros(len(p), np.int16)
    hidden = np.zeros(len(p), np.int16)
    for v in views:
        cam = v.camera
        T = cam.T_camera_world
        pc = p @ T[:3, :3].T + T[:3, 3]
        z = pc[:, 2]
        front = z > 1e-6
        zs = np.where(front, z, 1.0)
        u = np.rint(cam.fx * pc[:, 0] / zs + cam.cx).astype(np.int64)
        w = np.rint(cam.fy * pc[:, 1] / zs + cam.cy).astype(np.int64)
        ok = front & (u >= 0) & (u < cam.width) & (w >= 0) & (w < cam.height)
        d = np.full(len(p), np.nan, np.float32)
        d[ok] = v.depth[w[ok], u[ok]]
        ok &= np.isfinite(d)
        seen += ok
        hidden += ok & (z > d + tolerance)
    return (seen > 0) & (hidden == seen)


def distance_grid(points: np.ndarray, grid: Grid) -> np.ndarray:
    """Flat (cells,) float32 distance in metres from each cell centre to the nearest occupied cell centre."""
    from scipy.ndimage import distance_transform_edt

    occ = np.zeros(grid.shape, bool)
    idx, inside = grid.index(points)
    occ.reshape(-1)[idx[inside]] = True
    if not occ.any():
        return np.full(int(np.prod(grid.shape)), np.inf, np.float32)
    return (distance_transform_edt(~occ) * grid.cell).astype(np.float32).reshape(-1)


def palm_and_unseen(R, centre, width, grid, dgrid, palm_s, palm_thr, palm_depth, tree, tree_pts, fl_s, fr_s, views,
                     cfg, cache):
    """(ok (C,), clearance (C,) metres, palm ok (C,)) of candidates with frames R (C,3,3) at ``centre``."""
    g = cfg.gripper
    palm_w = np.einsum("cij,sj->csi", R, palm_s) + centre[:, None]
    pidx, pin = grid.index(palm_w)
    pd = np.where(pin, dgrid[pidx], np.inf)
    palm_min = pd.min(axis=1)
    palm_ok = palm_min >= palm_thr  # provably free (cover radius + grid error + pad)
    # provably hit: a point within D + cell*sqrt(3) of a sample lying deeper than that inside the palm
    sure_hit = np.any(pd + grid.cell * np.sqrt(3) < palm_depth[None] + cfg.collision_pad, axis=1)
    unsure = np.flatnonzero(~palm_ok & ~sure_hit)
    if len(unsure):  # exact: the cloud points near the palm, in the candidate's frame
        box = g.boxes(g.max_width)["palm"]
        pc = np.asarray(box.centre)
        c_w = R[unsure] @ pc + centre[unsure]
        nb = tree.query_ball_point(c_w, float(np.linalg.norm(box.half)) + cfg.collision_pad)
        lens = np.fromiter((len(n) for n in nb), np.int64, len(nb))
        flat = np.concatenate([np.asarray(n, np.int64) for n in nb])
        owner = np.repeat(np.arange(len(unsure)), lens)
        loc = np.einsum("nji,nj->ni", R[unsure][owner], tree_pts[flat] - centre[unsure][owner])
        inside = box.contains(loc, cfg.collision_pad)
        hit = np.bincount(owner[inside], minlength=len(unsure)) > 0
        palm_ok[unsure[~hit]] = True
    shift = (width - g.max_width) / 2  # move the fully opened fingers in to this width
    fing = np.concatenate([np.broadcast_to(fl_s, (len(R),) + fl_s.shape),
                           np.broadcast_to(fr_s, (len(R),) + fr_s.shape)], axis=1).copy()
    nl = len(fl_s)
    fing[:, :nl, 0] -= shift[:, None]
    fing[:, nl:, 0] += shift[:, None]
    fing_w = np.einsum("cij,csj->csi", R, fing) + centre[:, None]
    fidx, fin = grid.index(fing_w)
    finger_min = np.where(fin, dgrid[fidx], np.inf).min(axis=1)
    ok = palm_ok.copy()
    if views and ok.any():
        cells = np.concatenate([pidx[ok][pin[ok]], fidx[ok][fin[ok]]])
        cand = np.concatenate([np.repeat(np.flatnonzero(ok), pin[ok].sum(1)),
                               np.repeat(np.flatnonzero(ok), fin[ok].sum(1))])
        mark = np.zeros(len(cache), bool)  # cells not classified yet (cache: -1 unknown, 0 free, 1 occupied)
        mark[cells[cache[cells] < 0]] = True
        todo = np.flatnonzero(mark)
        if len(todo):
            ijk = np.stack(np.unravel_index(todo, grid.shape), axis=1)
            cache[todo] = unseen_occupied(grid.origin + (ijk + 0.5) * grid.cell, views, cfg.hidden_tolerance)
        hit = np.bincount(cand[cache[cells] > 0], minlength=len(R)) > 0
        ok &= ~hit
    # clearance beyond each part's acceptance threshold; the fingers sit near the target by design,
    # so their distance counts from the grid's own error only
    clear = np.minimum(palm_min - (palm_thr - cfg.collision_pad), finger_min - cfg.grid_cell * np.sqrt(3))
    return ok, clear, palm_ok
