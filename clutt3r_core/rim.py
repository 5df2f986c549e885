"""Rim voxels: kept by the fusion apart from the segmented cloud, labelled after the vote (ours, issue 13).

With the surface estimate (``clutt3r_core.surface``), a voxel holding a single raw point that the
estimate could not move, next to kept voxels, is a *rim* voxel (``PointCloudConfig.
surface_rim_neighbours``): object rims, where depth edges and grazing views leave sparse samples,
were the largest share of the object surface without a fused point. Segmented together with
the cloud they raised AP but cost hard AP50 (a spurious instance or a fragment on 2 of 6 hard
scenes: they bridge objects in the super-voxel graph). So the fusion returns them apart
(``FusedCloud.rim``), the cloud is segmented as without them, and each rim voxel then takes the
majority label of its ``k`` nearest segmented voxels (``attach_labels``); the pipeline appends
them to the segmentation's points, so everything downstream sees one cloud
(docs/benchmark/strict-iou.md, third pass).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from clutt3r_core.errors import SceneError
from clutt3r_core.scene import _frozen_array as _readonly  # the scene types' read-only array rule

__all__ = ["RimVoxels", "Attached", "attach_labels", "split_rim", "rim_apart"]


@dataclass(frozen=True, eq=False)
class RimVoxels:
    """The rim voxels of a fusion, not part of the segmented cloud (module docstring).

    Attributes:
        points: (R, 3) float32 world metres, the voxel's one (moved) raw point.
        colors: (R, 3) uint8 RGB of that point.
        normals: (R, 3) float32 unit, the normal of the nearest cloud voxel (a rim voxel has too
            few neighbours on its own side of the edge for a PCA normal of its own).
        counts: (R,) int32 raw points in the voxel (1: that is what makes it a rim voxel).
    """

    points: np.ndarray
    colors: np.ndarray
    normals: np.ndarray
    counts: np.ndarray

    def __post_init__(self) -> None:
        pts = np.asarray(self.points, np.float32)
        if pts.ndim != 2 or pts.shape[1] != 3:
            raise SceneError(f"RimVoxels.points must be (R, 3), got {pts.shape}")
        r = len(pts)
        cols = np.asarray(self.colors)
        if cols.shape != (r, 3) or cols.dtype != np.uint8:
            raise SceneError(f"RimVoxels.colors must be ({r}, 3) uint8, got {cols.dtype} {cols.shape}")
        nrm = np.asarray(self.normals, np.float32)
        if nrm.shape != (r, 3):
            raise SceneError(f"RimVoxels.normals must be ({r}, 3), got {nrm.shape}")
        cnt = np.asarray(self.counts, np.int32).reshape(-1)
        if cnt.shape != (r,) or (r and cnt.min() < 1):
            raise SceneError(f"RimVoxels.counts must be ({r},) and >= 1, got {cnt.shape}")
        for name, a in (("points", pts), ("colors", cols), ("normals", nrm), ("counts", cnt)):
            object.__setattr__(self, name, _readonly(a))

    @property
    def num(self) -> int:
        return int(self.points.shape[0])


def split_rim(P, C, pix_list, offsets, rim):
    """The fusion's raw points without the rim points, and the rim points apart.

    P (P, 3) float32 world metres, C (P, 3) uint8, ``pix_list[v]`` the flat pixel indices of view v's
    points, ``offsets`` (V + 1,), ``rim`` (P,) bool (a rim voxel holds one point: a rim point is a
    rim voxel). Returns P, C, pix_list, offsets without them (a rim point feeds no pixel of the
    segmented cloud) and (rim points (R, 3), their colours (R, 3))."""
    from clutt3r_core.pointcloud import _keep_points  # it imports this module

    return (*_keep_points(P, C, pix_list, offsets, ~rim), (np.compress(rim, P, axis=0), np.compress(rim, C, axis=0)))


def rim_apart(points: np.ndarray, colors: np.ndarray, cloud_points: np.ndarray,
              cloud_normals: np.ndarray) -> RimVoxels | None:
    """``RimVoxels`` of rim points (R, 3) / colours (R, 3), each with the normal of the nearest cloud
    voxel (``cloud_points`` (N, 3), ``cloud_normals`` (N, 3)); None without a cloud voxel."""
    if len(cloud_points) == 0 or len(points) == 0:
        return None
    from clutt3r_core.normals import knn_query, knn_tree

    near = knn_query(knn_tree(cloud_points), points, 1)[1].reshape(-1)
    return RimVoxels(points, colors, np.asarray(cloud_normals, np.float32)[near], np.ones(len(near), np.int32))


@dataclass(frozen=True, eq=False)
class Attached:
    """Labels of attached points (``attach_labels``).

    Attributes:
        label: (R,) int32, the majority label among the point's ``k`` nearest labelled points
            within ``max_distance``; -1 (unlabelled) counts as a label; -1 also when none lies
            within ``max_distance``.
        source: (R,) int64 index of the nearest of those neighbours that carry ``label`` (the one
            whose super-voxel the point joins); the nearest point at all when none lies within
            ``max_distance``.
    """

    label: np.ndarray
    source: np.ndarray

    def __post_init__(self) -> None:
        lab = np.asarray(self.label, np.int32).reshape(-1)
        src = np.asarray(self.source, np.int64).reshape(-1)
        if lab.shape != src.shape:
            raise SceneError(f"Attached: label {lab.shape} and source {src.shape} must agree")
        object.__setattr__(self, "label", _readonly(lab))
        object.__setattr__(self, "source", _readonly(src))


def attach_labels(points: np.ndarray, labels: np.ndarray, query: np.ndarray, k: int,
                  max_distance: float) -> Attached:
    """Label each ``query`` point by the majority of its ``k`` nearest ``points`` (module docstring).

    points: (N, 3) float world metres, the labelled points (N >= 1 when there is a query);
    labels: (N,) int, -1 = unlabelled (a label like any other here); query: (R, 3) float world
    metres; k >= 1 neighbours; max_distance: metres, neighbours farther away do not vote. Equal
    counts go to the label whose nearest voter is nearest (``normals.knn_query``: equal distances
    among the k found are ordered by index; which of several points tied at the k-th distance
    is found is the tree's choice). A query point never changes a labelled point's label, and its label is always one
    of its voters' (or -1 without voters).
    """
    points = np.asarray(points, np.float64).reshape(-1, 3)
    labels = np.asarray(labels).reshape(-1)
    query = np.asarray(query, np.float64).reshape(-1, 3)
    if labels.shape != (len(points),):
        raise SceneError(f"attach_labels: labels must be ({len(points)},), got {labels.shape}")
    if k < 1 or not max_distance >= 0:
        raise SceneError(f"attach_labels needs k >= 1 and max_distance >= 0, got {k}, {max_distance}")
    r = len(query)
    if r == 0:
        return Attached(np.zeros(0, np.int32), np.zeros(0, np.int64))
    if len(points) == 0:
        raise SceneError("attach_labels: no labelled points to attach to")
    from clutt3r_core.normals import knn_query, knn_tree

    k = min(k, len(points))
    # knn_query orders equal distances among the k found by index (pykdtree's query does not)
    # and runs a small query on one OpenMP thread; sqrt of its squared distances equals pykdtree's
    d2, j = knn_query(knn_tree(points), query, k)
    d, j = np.sqrt(d2), j.astype(np.int64)
    lab = labels[j]
    voter = d <= max_distance
    # votes for the label at each position among the voters; a position that does not vote has -1
    same = (lab[:, :, None] == lab[:, None, :]) & voter[:, None, :]
    votes = np.where(voter, same.sum(axis=2), -1)
    # the most votes, then the nearest position (positions are in ascending distance)
    best = np.argmax(votes * (k + 1) - np.arange(k)[None, :], axis=1)
    rows = np.arange(r)
    none = ~voter[:, 0]  # the nearest is farther than max_distance: no voter at all
    label = np.where(none, -1, lab[rows, best])
    return Attached(label.astype(np.int32), j[rows, np.where(none, 0, best)])
