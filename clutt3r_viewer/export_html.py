"""A run as one standalone HTML page (``clutt3r export-html RUN OUT.html``, issue 16).

The page is viser's own client with the scene embedded (``ViserServer.scene.as_html()``): the
cloud coloured by instance (the corrected labels when the run has edits), one label per
instance at its centroid, the run's grasps (``grasps.npz``) as gripper outlines, the camera
frustums, and the viewer's default camera. It opens from a file (``file://``), without a server
or network: for a paper's supplement or a bug report. The Scene tab of ``clutt3r view`` and the
guided tour offer the same page as a download.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from clutt3r_viewer.headless import free_port
from clutt3r_viewer.data import ViewerData, label_colors, lod_indices, ramp_colors

__all__ = ["scene_html", "export_html", "MAX_POINTS"]

MAX_POINTS = 200_000  # points embedded (level of detail): a 200k-point page is ~3 MB and opens in a second


def scene_html(data: ViewerData, instance: np.ndarray | None = None, max_points: int = MAX_POINTS,
               point_size: float = 0.006, frustums: bool = True) -> str:
    """The standalone page of ``data`` (module docstring) as a string.

    Args:
        instance: (N,) int32 instance per point to colour by (default: the run's own).
        max_points: points embedded (a deterministic subset, as the viewer's level of detail).
    """
    import viser
    import viser.transforms as vtf

    from clutt3r_viewer.camera import default_camera, frustum_scale
    from clutt3r_viewer.panels.grasps import gripper_segments

    seg = data.seg
    lab = seg.instance if instance is None else np.asarray(instance)
    if lab.shape != (len(seg.points),):
        raise ValueError(f"instance labels must be ({len(seg.points)},), got {lab.shape}")
    # a private server on a free local port: as_html() serialises its broadcast scene; no tab connects
    server = viser.ViserServer(host="127.0.0.1", port=free_port(), verbose=False)
    try:
        sc = server.scene
        sc.set_up_direction("+z")
        sc.world_axes.visible = False
        idx = lod_indices(len(seg.points), max_points)
        centre = data.centre
        sc.add_point_cloud("/cloud", (seg.points[idx] - centre).astype(np.float32), label_colors(lab[idx]),
                           point_size=point_size, point_shape="rounded", position=centre, precision="float16")
        for k in np.unique(lab[lab >= 0]):
            p = np.median(seg.points[lab == k], axis=0)
            sc.add_label(f"/instances/I{int(k)}", f"I{int(k)}", position=tuple(float(x) for x in p))
        g = data.grasps
        if g is not None and len(g):
            segs = np.concatenate([gripper_segments(g.poses[k], g.widths[k]) for k in range(len(g))])
            col = np.repeat(ramp_colors(g.scores, float(g.scores.min()), float(g.scores.max())), 4, axis=0)
            sc.add_line_segments("/grasps", segs, np.repeat(col[:, None], 2, axis=1), thickness=2.0,
                                 thickness_units="screen")
        if frustums and data.views:
            s = frustum_scale(data)
            for vi, v in enumerate(data.views):
                cam = v.camera
                sc.add_camera_frustum(f"/cameras/view{vi}", fov=float(2 * np.arctan2(cam.height / 2, cam.fy)),
                                      aspect=cam.width / cam.height, scale=s, thickness=2.0, thickness_units="screen",
                                      wxyz=vtf.SO3.from_matrix(cam.T_world_camera[:3, :3]).wxyz,
                                      position=cam.T_world_camera[:3, 3], color=(60, 60, 60))
        pose = default_camera(data)
        server.initial_camera.fov = pose.fov
        server.initial_camera.position = tuple(float(x) for x in pose.position)
        server.initial_camera.look_at = tuple(float(x) for x in pose.look_at)
        return sc.as_html()
    finally:
        server.stop()


def export_html(data: ViewerData, out: str | Path, instance: np.ndarray | None = None,
                max_points: int = MAX_POINTS) -> Path:
    """Write ``scene_html`` to ``out``; returns the path."""
    from clutt3r_core.io.images import atomic_write_bytes

    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(out, scene_html(data, instance, max_points).encode("utf-8"))
    return out
