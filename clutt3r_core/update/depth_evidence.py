"""The evidence a depth fit needs that the object is there (ours, session 7; used by
``depth_change``, its step 5): a registration that passed the ``accept_*`` tests can still be
a removed object's pose on another surface (a flat object on the table, a mask that is an
in-place neighbour's). Measured reasons in docs/update.md "Session 7: removed objects"."""

from __future__ import annotations

from functools import cache

import numpy as np
from scipy.spatial import cKDTree

from clutt3r_core.scene import View
from clutt3r_core.update.associate import Association
from clutt3r_core.update.depth import Registration, _on_or_in_front
from clutt3r_core.update.types import UpdateConfig

__all__ = ["FitEvidence"]


class FitEvidence:
    """The evidence a fit that passed the ``accept_*`` tests still needs (ours, session 7):
    ``__call__(k, registration, target points, mask index or -1, target pixels)`` is False
    when the fit is refused (the reason goes into ``refused[k]``).

    - ``ChangeConfig.fit_plane_colour``: a target standing on the support plane (its 95th
      height percentile under ``in_place_tol``) must look like the instance more than like the
      support (the depth cannot tell a flat object from the table).
    - ``ChangeConfig.fit_owner_appearance``: a mask the association gave to an in-place
      instance must look more like the fitted instance than like that one (S_semantic); a
      target without a mask (an unexplained region, a pair of masks) must look more like the
      fitted instance than like the in-place instance nearest to its depth points (the one
      whose surface it would continue), by ``embed`` (the association's embedder), when given."""

    def __init__(self, state, view: View, config: UpdateConfig, assoc: Association, in_place: set, support,
                 refused: dict, embed=None) -> None:
        self.state, self.view, self.cc, self.support, self.refused = state, view, config.change, support, refused
        self.in_place = in_place
        self.col = {int(k): i for i, k in enumerate(assoc.instance_ids)}
        self.owner = {int(mi): int(k) for k, mi in zip(assoc.instance_ids, assoc.mask_index) if mi >= 0}
        self.s_sem = assoc.s_semantic
        self.embed = embed
        ip = np.isin(state.instance, np.array(sorted(in_place), np.int32))
        self._ip = cache(lambda: (cKDTree(state.points[ip]), state.instance[ip]) if ip.any() else None)
        self._bg = cache(lambda: (state.points[state.instance < 0].astype(np.float64),
                                  state.colors[state.instance < 0].astype(np.float64)))

    def __call__(self, k: int, reg: Registration, pts: np.ndarray, mask_index: int,
                 pixels: np.ndarray | None = None) -> bool:
        cc = self.cc
        if cc.fit_owner_appearance and mask_index < 0 and pixels is not None and not self._neighbour_ok(k, pts, pixels):
            self.refused[k] = "neighbour-appearance"
            return False
        if cc.fit_owner_appearance and mask_index >= 0 and not self._owner_ok(k, mask_index):
            self.refused[k] = "owner-appearance"
            return False
        if cc.fit_plane_colour and not self._plane_colour_ok(k, reg, pts):
            self.refused[k] = "plane-colour"
            return False
        return True

    def _neighbour_ok(self, k: int, pts: np.ndarray, pixels: np.ndarray) -> bool:
        near = self._ip()
        if self.embed is None or near is None or not len(pts):
            return True
        tree, lab = near
        j = int(np.bincount(lab[tree.query(pts)[1]] - lab.min()).argmax() + lab.min())
        e = np.asarray(self.embed(pixels[None]), np.float32)[0]
        E = np.asarray(self.state.embeddings, np.float32)
        return float(e @ E[self.col[k]]) >= float(e @ E[self.col[j]])

    def _owner_ok(self, k: int, mi: int) -> bool:
        j = self.owner.get(mi)
        if j is None or j == k or j not in self.in_place:
            return True
        a, b = float(self.s_sem[mi, self.col[k]]), float(self.s_sem[mi, self.col[j]])
        # S_semantic is computed for the masks that reached the semantic stage only (NaN else)
        return not (np.isfinite(a) and np.isfinite(b)) or a >= b

    def _plane_colour_ok(self, k: int, reg: Registration, pts: np.ndarray) -> bool:
        view, cc = self.view, self.cc
        plane = self.support()
        if plane is None or view.rgb is None or not len(pts):
            return True
        if np.percentile(pts @ plane[:3] + plane[3], 95) >= cc.in_place_tol:
            return True  # stands above the support: the depth tells object from table
        sel = self.state.instance == k
        T = reg.T_world
        uv, on, _ = _on_or_in_front(self.state.points[sel].astype(np.float64) @ T[:3, :3].T + T[:3, 3],
                                    view.camera, view.depth, cc.in_place_tol)
        if not on.any():
            return False
        H, W = view.depth.shape
        u = np.clip(np.round(uv[on, 0]).astype(np.int64), 0, W - 1)
        v = np.clip(np.round(uv[on, 1]).astype(np.int64), 0, H - 1)
        img = view.rgb[v, u].astype(np.float64)
        bg, bg_col = self._bg()
        if not len(bg):
            return True
        near = np.linalg.norm(bg - pts.mean(axis=0), axis=1) <= cc.support_colour_radius
        table = np.median(bg_col[near] if near.any() else bg_col, axis=0)
        obj = self.state.colors[sel][on].astype(np.float64)
        return float(np.abs(img - obj).mean()) < float(np.abs(img - table).mean())
