"""Rigid pose update of one displaced instance from one new image, in torch on the CPU (Sec. III-C).

Parameterisation (``PoseConfig.dof``):

- ``se3``: a rotation vector w (axis-angle, radians, world axes) about the instance's centroid c
  and a translation t (world metres): ``p' = R(w) (p - c) + c + t``, so
  ``T_world = [[R, c + t - R c], [0, 1]]``. Rotating about c keeps rotation and translation
  decoupled (a turn in place does not move the centroid), and t_z is directly the vertical
  motion that L_reg,z penalises.
- ``yaw``: w = (0, 0, theta): a turn about the world z axis through c, plus t (4 DoF).
- ``yaw-then-se3``: the coarse stage in yaw + t, the fine stage in full SE(3).

The default is ``yaw``: roll and pitch are poorly observed from one silhouette and drift
during the search (measured in docs/update.md); objects pushed on a table turn mostly about
the vertical. All three share one parameter vector (w, t); a stage's mask zeroes the unused
rotation components.

Objective (eq. 6): ``L = l_chamfer L_chamfer + l_photo L_photo + l_reg,z L_reg,z (+ l_depth L_depth)``

- L_chamfer (eq. 7): bidirectional mean nearest distance between P, the projections of the
  instance's *contour points* (visible points whose splat touches the edge of the current
  projected silhouette) and C, the boundary pixels of the target mask eroded by the splat
  radius (a splat centre lies that far inside the silhouette edge). Pixels divided by the
  image diagonal (ours: the paper gives no unit; this keeps the Sec. IV weights meaningful
  at any resolution).
- L_photo: weighted L1 between point colours and the image sampled bilinearly at their
  projections, in [0, 1] per channel; weight 1 for points visible at the current pose
  (self z-buffer and not behind other instances), 0 otherwise.
- L_reg,z: ``(t_z / sigma_z)^2``.
- L_depth (ours, only when the new view has depth): Huber (1 cm) of the camera z of visible
  points inside the mask against the new depth, in cm.

Schedule: every yaw start of ``yaw_starts_deg`` runs ``probe_iterations`` coarse steps from
the translation that puts the centroid on the ray through the mask centroid at its old
height; the lowest coarse loss continues to ``coarse.iterations`` steps. If the IoU then
reaches tau_IoU the optimisation ends (early exit, Sec. III-C), else the fine stage runs
with the fine weights. Every step is recorded (pose, losses, IoU).
"""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np
from scipy import ndimage

from clutt3r_core.update.pose_ops import _Adam, _near_outside
from clutt3r_core.update.project import OCCLUSION_MARGIN, splat, splat_radius
from clutt3r_core.update.types import LOSS_NAMES, PoseConfig, PoseProblem, PoseResult, PoseTrace, StageConfig

__all__ = ["TorchPoseOptimizer", "motion_matrix", "initial_translation", "tilted_start"]


def motion_matrix(R: np.ndarray, c: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(4, 4) world motion of a rotation R about the point c followed by a translation t."""
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = c + t - R @ c
    return T


def initial_translation(problem: PoseProblem, centroid: np.ndarray) -> np.ndarray:
    """(3,) translation that puts the centroid on the viewing ray of the mask's centroid, at its
    old height (the objects rest on the table; L_reg,z keeps them there)."""
    vs, us = np.nonzero(problem.mask)
    if not len(us):
        return np.zeros(3)
    cam = problem.camera
    ray_c = np.linalg.solve(cam.K, np.array([us.mean(), vs.mean(), 1.0]))
    o = cam.T_world_camera[:3, 3]
    d = cam.T_world_camera[:3, :3] @ ray_c
    if abs(d[2]) > 1e-6 and (centroid[2] - o[2]) / d[2] > 0:
        s = (centroid[2] - o[2]) / d[2]
    else:  # a ray parallel to the table: keep the centroid's camera depth instead
        s = float((cam.T_camera_world[:3, :3] @ centroid + cam.T_camera_world[:3, 3])[2])
    return o + s * d - centroid


class TorchPoseOptimizer:
    """``PoseOptimizer`` (registry name ``torch-adam``): Adam over (w, t), see the module docstring."""

    name = "torch-adam"

    def __init__(self, config: PoseConfig | None = None, threads: int = 1) -> None:
        import torch  # heavy import at construction, as every backend

        self._torch = torch
        self.config = config or PoseConfig()
        # Small problems: one thread avoids OpenMP overhead and leaves the other core free.
        self.threads = int(threads)

    def optimize(self, problem: PoseProblem) -> PoseResult:
        torch = self._torch
        prev_threads = torch.get_num_threads()
        torch.set_num_threads(self.threads)
        try:
            if problem.T_init is None and self.config.tilt_starts:
                T = tilted_start(problem, self.config)
                if T is not None:  # a tipped-over placement explains the mask better: start there
                    problem = replace(problem, T_init=T)
            return _Solver(problem, self.config, torch).run()
        finally:
            torch.set_num_threads(prev_threads)


_PLACEMENT_POINTS = 250
"""Ours: points per placement of ``tilted_start`` (subsampled, splats enlarged to close the
silhouette): its 72 splats were 1/5 of an RGB-only update's CPU on sample_seq1 at 600 points."""


def _placements(problem: PoseProblem, cfg: PoseConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(S, 4, 4) motions of the start placements, (S,) their score, (S,) bool upright."""
    from clutt3r_core.update.depth import start_rotations

    pts = problem.points.astype(np.float64)
    cols = problem.colors.astype(np.float64)
    c = pts.mean(axis=0)
    n = min(cfg.max_points, _PLACEMENT_POINTS)  # 72 placements: a coarse silhouette is enough
    if len(pts) > n:
        idx = np.sort(np.random.default_rng(0).choice(len(pts), n, replace=False))
        pts, cols = pts[idx], cols[idx]
    scale = float(np.sqrt(len(problem.points) / len(pts)))
    Rs = start_rotations(cfg.tilt_yaw_step_deg, tilts=True)
    n_up = len(start_rotations(cfg.tilt_yaw_step_deg, tilts=False))
    cam = problem.camera
    vs, us = np.nonzero(problem.mask)
    o = cam.T_world_camera[:3, 3]
    d = cam.T_world_camera[:3, :3] @ np.linalg.solve(cam.K, np.array([us.mean(), vs.mean(), 1.0]))
    zmin = pts[:, 2].min()
    area = int(np.count_nonzero(problem.mask))
    Ts, scores = [], []
    for R in Rs:
        q = (pts - c) @ R.T + c
        height = c[2] + zmin - q[:, 2].min()  # resting on the same support height
        sray = (height - o[2]) / d[2] if abs(d[2]) > 1e-6 else 0.0
        t = (o + sray * d - c) if sray > 0 else initial_translation(problem, c)
        T = motion_matrix(R, c, t)
        p = pts @ T[:3, :3].T + T[:3, 3]
        sp = splat(p, cam, problem.voxel_size, scale, with_points=False)
        if not (sp.h and sp.w):
            Ts.append(T)
            scores.append(0.0)
            continue
        iou = _window_iou(sp, sp.silhouette(problem.occluder_depth), problem.mask, area)
        # colours of the points it shows (a box tipped on its side shows other faces)
        vis = sp.visible(problem.occluder_depth)
        photo = 0.0
        if vis.any():
            img = sp.crop(problem.rgb).reshape(-1, 3)[sp.centre[vis]].astype(np.float64)
            photo = float(np.mean(np.abs(img - cols[vis]).mean(axis=1) <= cfg.tilt_color_tol))
        Ts.append(T)
        scores.append(iou * (0.5 + 0.5 * photo))
    up = np.zeros(len(Rs), bool)
    up[:n_up] = True
    return np.stack(Ts), np.array(scores), up


def tilted_start(problem: PoseProblem, cfg: PoseConfig) -> np.ndarray | None:
    """The best tipped-over start placement (``PoseConfig.tilt_starts``), or None when an upright
    one scores within ``tilt_margin`` of it (then the paper's yaw starts run as before).

    Placements: the start rotations of the depth registration (the six ways the object's up
    axis can point x yaws every ``tilt_yaw_step_deg``) about the centroid, resting on the
    same support height, the centroid on the viewing ray of the mask's centroid. Score = IoU
    of the occluded silhouette with the mask x (0.5 + 0.5 x the fraction of its visible
    points whose stored colour is within ``tilt_color_tol`` of the image)."""
    if not problem.mask.any():
        return None
    Ts, score, up = _placements(problem, cfg)
    if score[~up].max() < score[up].max() + cfg.tilt_margin:
        return None
    return Ts[int(np.argmax(np.where(up, -1.0, score)))]


def _window_iou(sp, sil: np.ndarray, mask: np.ndarray, mask_area: int) -> float:
    """IoU of a window silhouette (``Splats.silhouette``) with a full (H, W) mask of
    ``mask_area`` pixels (the mask outside the window counts in the union)."""
    inter = int(np.count_nonzero(sil & sp.crop(mask)))
    union = int(np.count_nonzero(sil)) + mask_area - inter
    return inter / union if union else 0.0


class _Solver:
    def __init__(self, pb: PoseProblem, cfg: PoseConfig, torch) -> None:
        t0 = time.perf_counter()
        self.pb, self.cfg, self.torch = pb, cfg, torch
        self.t_start = t0
        cam = pb.camera
        H, W = cam.height, cam.width
        self.H, self.W = H, W
        self.diag = float(np.hypot(H, W))
        pts = pb.points.astype(np.float64)
        self.T_init = np.eye(4) if pb.T_init is None else np.asarray(pb.T_init, np.float64)
        if pb.T_init is not None:  # optimise a correction of the given start (matrix() composes it)
            pts = pts @ self.T_init[:3, :3].T + self.T_init[:3, 3]
        self.all_points = pts
        self.c = pts.mean(axis=0)
        rng = np.random.default_rng(0)
        sub = np.sort(rng.choice(len(pts), cfg.max_points, replace=False)) if len(pts) > cfg.max_points else np.arange(len(pts))
        self.sub_scale = float(np.sqrt(len(pts) / len(sub)))  # sparser points: bigger splats close the silhouette
        self.p = torch.tensor(pts[sub] - self.c, dtype=torch.float64)
        self.col = torch.tensor(pb.colors[sub].astype(np.float64) / 255.0)
        self.col_all = self.col.repeat(len(cfg.yaw_starts_deg), 1)  # rows of the batched probe
        Tcw = cam.T_camera_world
        self.Rcw = torch.tensor(Tcw[:3, :3])
        self.tcw = torch.tensor(Tcw[:3, 3])
        self.c_t = torch.tensor(self.c)
        self.K = cam.K
        self.img = torch.tensor(pb.rgb.astype(np.float32) / 255.0).permute(2, 0, 1)[None].double()
        self.mask = pb.mask
        self.occ2d = pb.occluder_depth.astype(np.float64)
        self.occ_flat = self.occ2d.reshape(-1)
        self.depth = self.depth2d = None if pb.depth is None else pb.depth.astype(np.float64)
        self.mask_area = int(np.count_nonzero(pb.mask))
        # target contour: boundary of the mask eroded by the typical splat radius
        z0 = (pts @ Tcw[:3, :3].T + Tcw[:3, 3])[:, 2]
        r = int(np.median(splat_radius(z0[z0 > 0], cam, pb.voxel_size))) if (z0 > 0).any() else 1
        eroded = ndimage.binary_erosion(pb.mask, iterations=r) if r > 0 else pb.mask
        if not eroded.any():
            eroded = pb.mask
        edge = eroded & ~ndimage.binary_erosion(eroded)
        vs, us = np.nonzero(edge)
        step = max(1, int(np.ceil(len(us) / cfg.max_contour)))
        self.C = torch.tensor(np.stack([us[::step], vs[::step]], axis=1).astype(np.float64))
        # Kx = (_gen @ w).view(3, 3) = [[0, -w2, w1], [w2, 0, -w0], [-w1, w0, 0]]
        self._gen = torch.tensor([[0, 0, 0], [0, 0, -1], [0, 1, 0], [0, 0, 1], [0, 0, 0], [-1, 0, 0],
                                  [0, -1, 0], [1, 0, 0], [0, 0, 0]], dtype=torch.float64)
        self._eye = torch.eye(3, dtype=torch.float64)
        self.f_uv = torch.tensor([self.K[0, 0], self.K[1, 1]])
        self.c_uv = torch.tensor([self.K[0, 2], self.K[1, 2]])
        # grid_sample's [-1, 1] coordinates (align_corners=True) as one affine map of (u, v)
        # (float32 values, as the poses were recorded with; held in float64 so that each step's
        # product does not convert them again: the same products, one op less per step)
        self.g_scale = torch.tensor([2.0 / (W - 1), 2.0 / (H - 1)], dtype=torch.float32).double()
        self.yaw_mask = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)
        self.full_mask = torch.ones(3, dtype=torch.float64)
        self.rot_mask = self.full_mask if cfg.dof == "se3" else self.yaw_mask

    # -- geometry ------------------------------------------------------------------------
    # Parameters are (B, 3) tensors, one row per yaw start: the probe evaluates its B starts in
    # one batched pass (ours: each small torch op costs ~10 us of overhead forward and back, so
    # B starts cost little more than one; measured in docs/update.md). Rows never mix: every
    # operation is row-wise or a per-row (segment) mean, so the gradient of the summed loss
    # gives each row its own gradient, and Adam is elementwise.
    def rotation(self, w):
        """(B, 3, 3) Rodrigues' formula of the (B, 3) rotation vectors (differentiable; rows with
        theta^2 < 1e-12 take the small-angle form I + [w]x, which avoids 0/0 at w = 0).

        The cross-product matrices are one product with the constant (9, 3) generator ``_gen``
        (each entry is +-1 x one component plus zeros: the same values as stacking them)."""
        torch = self.torch
        theta2 = (w * w).sum(dim=1)
        Kx = (w @ self._gen.T).view(-1, 3, 3)
        small_np = theta2.detach().numpy() < 1e-12  # the test in numpy: no tensor reductions, no syncs
        if small_np.all():
            return self._eye + Kx
        if small_np.any():  # safe values in the masked rows: their where() branch is not used
            small = torch.from_numpy(small_np)
            one = torch.ones_like(theta2)
            th2 = torch.where(small, one, theta2)
            th = th2.sqrt()
            a = torch.where(small, one, torch.sin(th) / th)
            b = torch.where(small, torch.zeros_like(theta2), (1 - torch.cos(th)) / th2)
        else:
            th = theta2.sqrt()
            a, b = torch.sin(th) / th, (1 - torch.cos(th)) / theta2
        return self._eye + a[:, None, None] * Kx + b[:, None, None] * (Kx @ Kx)

    def rotvec(self, params):
        # the mask of the running stage zeroes roll and pitch in the yaw stages (their Adam
        # state then stays at zero, so the SE(3) fine stage starts from the yaw result)
        return params["w"] * self.rot_mask

    def matrix(self, params, R, row: int = 0) -> np.ndarray:
        """The motion of row ``row`` of ``params``, whose rotations ``R`` (B, 3, 3) the loss just
        computed (``last_R``: the same values as computing them again)."""
        with self.torch.no_grad():
            return motion_matrix(R[row].detach().numpy(), self.c, params["t"][row].numpy()) @ self.T_init

    def _seg_mean(self, x, seg: np.ndarray, counts: np.ndarray):
        """(B,) mean of ``x`` (K,) per row ``seg`` (K,) int64 (rows ``counts`` (B,), 0 -> 0)."""
        torch = self.torch
        if len(counts) == 1:
            return x.mean()[None] if counts[0] else torch.zeros(1, dtype=torch.float64)
        s = torch.zeros(len(counts), dtype=torch.float64).index_add(0, torch.from_numpy(seg), x)
        return s / torch.from_numpy(np.maximum(counts, 1).astype(np.float64))

    # -- one evaluation ------------------------------------------------------------------
    def losses(self, params, stage: StageConfig):
        """(B,) total loss of each row of ``params`` and its (B,) terms; sets ``last_R`` (B, 3, 3)
        and ``last_iou`` (B,) list, the IoU of each row's splats."""
        torch, pb, cfg = self.torch, self.pb, self.cfg
        R = self.rotation(self.rotvec(params))
        self.last_R = R
        B, N = R.shape[0], len(self.p)
        pw = self.p @ R.transpose(1, 2) + (self.c_t + params["t"])[:, None, :]
        pc = pw @ self.Rcw.T + self.tcw
        z = pc[..., 2:].clamp(min=1e-3)
        uv = (pc[..., :2] / z * self.f_uv + self.c_uv).reshape(B * N, 2)
        # non-differentiable selection: visibility and contour membership at the current pose
        zn_all = pc[..., 2].detach().numpy()
        pw_np = pw.detach().numpy()
        cidx, vidx, cseg, vseg, dsel, dval, dseg = [], [], [], [], [], [], []
        n_c, n_v, n_d = np.zeros(B, np.int64), np.zeros(B, np.int64), np.zeros(B, np.int64)
        ious = []
        for b in range(B):
            zn = zn_all[b]
            sp = splat(pw_np[b], pb.camera, pb.voxel_size, self.sub_scale, with_points=False)
            inside = sp.centre >= 0
            cflat = np.maximum(sp.centre, 0)
            zb = sp.zbuf.reshape(-1)
            # the occluders' depth at the centre pixels, read from the full image (the window's
            # crop is not contiguous: reshaping it copied the whole window every step)
            occ_c = self.occ_flat[(cflat // sp.w + sp.v0) * self.W + cflat % sp.w + sp.u0] if sp.w else cflat * 0.0
            vis = inside & (zn <= zb[cflat] + OCCLUSION_MARGIN) & (zn <= occ_c + OCCLUSION_MARGIN)
            sil = sp.silhouette(self.occ2d)
            ious.append(_window_iou(sp, sil, self.mask, self.mask_area) if sp.h and sp.w else 0.0)
            if vis.any():
                # within the splat radius + 1.5 px of a pixel outside the silhouette (the window's
                # border is outside), at the visible points' centre pixels only
                contour = vis.copy()
                contour[vis] = _near_outside(sil, cflat[vis], sp.radius[vis] + 1.5)
            else:
                contour = vis
            ci = np.flatnonzero(contour) if contour.any() else np.arange(N)  # no contour: all points
            cidx.append(ci + b * N)
            n_c[b] = len(ci)
            vi = np.flatnonzero(vis)
            vidx.append(vi + b * N)
            n_v[b] = len(vi)
            if self.depth is not None:
                dn = sp.crop(self.depth2d).reshape(-1)[cflat]
                ok = vis & sp.crop(self.mask).reshape(-1)[cflat] & np.isfinite(dn)
                dsel.append(np.flatnonzero(ok) + b * N)
                dval.append(dn[ok])
                n_d[b] = int(ok.sum())
        self.last_iou = ious
        seg_c = np.repeat(np.arange(B), n_c) if B > 1 else None  # _seg_mean reads it for B > 1 only
        # integer indices and index_select: boolean-mask indexing runs a nonzero() and its
        # backward an index_put; each was ~50 us per step
        P = uv.index_select(0, torch.from_numpy(np.concatenate(cidx)))
        if len(self.C):
            # each point's nearest partner is chosen without gradient (the gradient of a minimum
            # flows through its argmin only) and the distances of those pairs are differentiated:
            # the same chamfer as min over torch.cdist, without the (|P|, |C|) backward; the
            # argmins by numpy (torch's argmin over dim 0 is ~4x slower on this strided matrix)
            with torch.no_grad():
                d = torch.cdist(P, self.C).numpy()
            near_c = d.argmin(axis=1)
            if B == 1:  # one row (every step after the probe): no per-row offsets, no repeat
                near_p, C_rows = d.argmin(axis=0), self.C
            else:
                starts = np.concatenate([[0], np.cumsum(n_c)[:-1]])
                near_p = np.concatenate([d[o : o + k].argmin(axis=0) + o for o, k in zip(starts, n_c)])
                C_rows = self.C.repeat(B, 1)
            d1 = (P - self.C.index_select(0, torch.from_numpy(near_c))).norm(dim=1)
            d0 = (P.index_select(0, torch.from_numpy(near_p)) - C_rows).norm(dim=1)
            chamfer = (self._seg_mean(d1, seg_c, n_c) + d0.view(B, -1).mean(dim=1)) / self.diag
        else:
            chamfer = torch.zeros(B, dtype=torch.float64)
        if n_v.any():
            # weight 1 for visible points, 0 otherwise: the mean over the visible ones
            iv = torch.from_numpy(np.concatenate(vidx))
            grid = (uv.index_select(0, iv) * self.g_scale - 1.0)[None, None]
            sampled = torch.nn.functional.grid_sample(self.img, grid, align_corners=True)[0, :, 0].T
            err = (sampled - self.col_all.index_select(0, iv)).abs().mean(dim=1)
            photo = self._seg_mean(err, np.repeat(np.arange(B), n_v) if B > 1 else None, n_v)
        else:
            photo = torch.zeros(B, dtype=torch.float64)
        reg_z = (params["t"][:, 2] / cfg.sigma_z) ** 2
        depth_term = torch.zeros(B, dtype=torch.float64)
        if self.depth is not None and n_d.any():
            okt = torch.from_numpy(np.concatenate(dsel))
            e = (pc[..., 2].reshape(-1).index_select(0, okt) - torch.from_numpy(np.concatenate(dval))) / 0.01
            hub = torch.nn.functional.huber_loss(e, torch.zeros_like(e), delta=1.0, reduction="none")
            depth_term = self._seg_mean(hub, np.repeat(np.arange(B), n_d), n_d)
        total = (stage.lambda_chamfer * chamfer + stage.lambda_photo * photo + stage.lambda_reg_z * reg_z
                 + (cfg.lambda_depth * depth_term if self.depth is not None else 0.0))
        return total, (chamfer, photo, reg_z, depth_term)

    def iou(self, T: np.ndarray) -> float:
        """IoU of the z-buffered projection of all points at motion T with the target mask."""
        T = T @ np.linalg.inv(self.T_init)  # T is a full motion of the stored points
        p = self.all_points @ T[:3, :3].T + T[:3, 3]
        sp = splat(p, self.pb.camera, self.pb.voxel_size, with_points=False)
        if not (sp.h and sp.w):
            return 0.0
        return _window_iou(sp, sp.silhouette(self.occ2d), self.mask, self.mask_area)

    # -- the schedule ----------------------------------------------------------------------
    def new_params(self, yaws: np.ndarray, t0: np.ndarray):
        """(B, 3) parameters (one row per start yaw, radians) and their Adam."""
        torch = self.torch
        B = len(yaws)
        t = torch.tensor(np.tile(t0, (B, 1)), dtype=torch.float64, requires_grad=True)
        w = np.zeros((B, 3))
        w[:, 2] = yaws
        r = torch.tensor(w, dtype=torch.float64, requires_grad=True)
        params = {"w": r, "t": t}
        return params, self._adam(params)

    def _adam(self, params) -> _Adam:
        """A fresh Adam over ``params``' rotation and translation, at their base learning rates."""
        return _Adam(self.torch, [{"params": [params["w"]], "lr": self.cfg.lr_rotation},
                                  {"params": [params["t"]], "lr": self.cfg.lr_translation}])

    def keep_row(self, params, opt, row: int):
        """The parameters and Adam state of one row (the probe's best start), as a batch of one."""
        new = {k: v.detach()[row : row + 1].clone().requires_grad_(True) for k, v in params.items()}
        opt2 = self._adam(new)
        for k in ("w", "t"):
            st = opt.state.get(id(params[k]))
            if st is not None:
                opt2.state[id(new[k])] = {"step": st["step"], "m": st["m"][row : row + 1].clone(),
                                          "v": st["v"][row : row + 1].clone()}
        return new, opt2

    def steps(self, params, opt, stage: StageConfig, stage_id: int, n: int, logs: list[list],
              decay: bool = True) -> None:
        """n Adam steps of every row of ``params``; row b's iterations go to ``logs[b]``."""
        scale = 1.0 if stage_id == 0 else self.cfg.fine_lr_scale
        base = [self.cfg.lr_rotation * scale, self.cfg.lr_translation * scale]
        for i in range(n):
            # exponential decay to 10 % over the stage (ours): large steps to travel, small to settle
            f = 0.1 ** (i / max(n - 1, 1)) if decay else 1.0
            for g, lr in zip(opt.param_groups, base):
                g["lr"] = lr * f
            opt.zero_grad()
            total, terms = self.losses(params, stage)
            vals = np.stack([total.detach().numpy()] + [x.detach().numpy() for x in terms], axis=1)
            # the IoU of an iteration comes from the splats the loss just made (subsampled points,
            # larger splats): measured on sample_seq1 the exact IoU of every step was 1/5 of an
            # update's CPU; the final IoU of each stage (early exit, verification) is exact
            for b, log in enumerate(logs):
                log.append((stage_id, self.matrix(params, self.last_R, b), vals[b].tolist(), self.last_iou[b]))
            total.sum().backward()
            opt.step()

    def final(self, params, stage: StageConfig, stage_id: int, log: list) -> None:
        with self.torch.no_grad():
            total, terms = self.losses(params, stage)
        T = self.matrix(params, self.last_R)
        log.append((stage_id, T, [float(total[0])] + [float(x[0]) for x in terms], self.iou(T)))

    def run(self) -> PoseResult:
        cfg = self.cfg
        iou_before = self.iou(np.eye(4))
        t0 = initial_translation(self.pb, self.c) if self.pb.T_init is None else np.zeros(3)
        yaws = np.deg2rad(np.asarray(cfg.yaw_starts_deg if self.pb.T_init is None else (0.0,), np.float64))
        # the probe: every start yaw runs probe_iterations coarse steps, in one batch; the lowest
        # coarse loss after them continues (the first on ties)
        params, opt = self.new_params(yaws, t0)
        logs: list[list] = [[] for _ in yaws]
        self.steps(params, opt, cfg.coarse, 0, min(cfg.probe_iterations, cfg.coarse.iterations), logs, decay=False)
        with self.torch.no_grad():
            score = self.losses(params, cfg.coarse)[0].numpy()
        row = int(np.argmin(score))
        params, opt = self.keep_row(params, opt, row)
        log = logs[row]
        self.steps(params, opt, cfg.coarse, 0, max(0, cfg.coarse.iterations - cfg.probe_iterations), [log])
        self.final(params, cfg.coarse, 0, log)
        stages = 1
        if not (cfg.early_exit and log[-1][3] >= cfg.tau_iou) and cfg.fine.iterations > 0:
            stages = 2
            if cfg.dof == "yaw-then-se3":
                self.rot_mask = self.full_mask
            self.steps(params, opt, cfg.fine, 1, cfg.fine.iterations, [log])
            self.final(params, cfg.fine, 1, log)
        trace = PoseTrace(
            stage=np.array([r[0] for r in log], np.int8),
            T_world=np.stack([r[1] for r in log]),
            losses=np.array([r[2] for r in log], np.float64).reshape(-1, len(LOSS_NAMES)),
            iou=np.array([r[3] for r in log], np.float64),
        )
        return PoseResult(T_world=trace.T_world[-1], iou_before=iou_before, iou_after=float(trace.iou[-1]),
                          trace=trace, stages=stages, seconds=time.perf_counter() - self.t_start)
