"""Write a run's trace to a rerun recording (.rrd), for the rerun viewer.

Entities (world is z up, metres):
    world/cloud                  the fused cloud in RGB (static)
    world/instances              instance points coloured by instance, labelled with confidence (static)
    world/cameras/viewN          pose + pinhole + image + mask candidates (static):
        .../image                 the RGB image (JPEG)
        .../image/leaves          leaf masks as a segmentation image, class = node index + 1,
                                  coloured by final instance (annotation context)
    world/replay                 the cloud coloured by the super-voxel vote of the groups so far,
                                 on the timeline ``grouping_event`` (0 = leaves alone, n = after event n);
                                 only colours change per step
    log/grouping                 the text of each event, same timeline
    world/updates/..., plots/update/..., updates/overlay, log/updates
                                 scene updates, when the run has some (panels/update_sources.py)

Saved with a recording stream's ``save`` (a file sink); no viewer is spawned.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from clutt3r_viewer.data import PALETTE, ViewerData, event_text, label_colors, lod_indices, node_label

__all__ = ["export_rerun"]


def export_rerun(data: ViewerData, out: str | Path, max_points: int = 50_000, image_max_width: int = 960) -> Path:
    """Write ``data``'s trace to ``out`` (.rrd). Returns the path.

    ``max_points`` caps the replay cloud (one colour array per event); ``image_max_width``
    downscales images and masks (1920x1080 samples stay readable at 960).
    """
    import rerun as rr

    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    seg, tr = data.seg, data.trace
    rec = rr.RecordingStream("clutt3r", recording_id=f"clutt3r-{seg.scene_name or 'run'}")
    tmp = out.with_name(out.name + ".tmp")
    rec.save(tmp)
    try:
        rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        rec.log("world/cloud", rr.Points3D(seg.points, colors=seg.colors, radii=0.002), static=True)
        inst = seg.instance
        has = inst >= 0
        labels = [f"I{k} conf {seg.scores[k]:.2f}" for k in range(seg.num_instances)]
        rec.log(
            "world/instances",
            rr.AnnotationContext([(k, labels[k], tuple(int(c) for c in PALETTE[k % len(PALETTE)]))
                                  for k in range(seg.num_instances)]),
            static=True,
        )
        rec.log("world/instances", rr.Points3D(seg.points[has], class_ids=inst[has], radii=0.003), static=True)

        nodes = tr.nodes
        for vi, v in enumerate(data.views):
            cam = v.camera
            s = max(1, int(np.ceil(cam.width / image_max_width)))
            K = cam.K.copy()
            K[:2] /= s
            h, w = v.rgb[::s, ::s].shape[:2]
            base = f"world/cameras/view{vi}"
            T = cam.T_world_camera
            rec.log(base, rr.Transform3D(translation=T[:3, 3], mat3x3=T[:3, :3]), static=True)
            rec.log(base, rr.Pinhole(image_from_camera=K, width=w, height=h, camera_xyz=rr.ViewCoordinates.RDF),
                    static=True)
            rec.log(f"{base}/image", rr.Image(np.ascontiguousarray(v.rgb[::s, ::s])).compress(jpeg_quality=85),
                    static=True)
            vn = data.view_nodes(vi)
            if v.masks is None or len(vn) == 0:
                continue
            seg_img = np.zeros((h, w), np.uint16)
            # big masks first: small leaves (proper segments) stay on top
            leaves = [int(i) for i in vn if nodes.is_leaf[i]]
            masks = {i: data.node_mask(i)[::s, ::s] for i in leaves}
            for i in sorted(leaves, key=lambda i: -int(masks[i].sum())):
                seg_img[masks[i]] = i + 1
            ctx = []
            for i in leaves:
                k = int(data.node_instance[i])
                col = PALETTE[k % len(PALETTE)] if k >= 0 else np.array([128, 128, 128])
                ctx.append((i + 1, f"{node_label(tr, i)} -> I{k}" if k >= 0 else node_label(tr, i),
                            tuple(int(c) for c in col)))
            rec.log(f"{base}/image/leaves", rr.AnnotationContext(ctx), static=True)
            rec.log(f"{base}/image/leaves", rr.SegmentationImage(seg_img), static=True)

        idx = lod_indices(len(seg.points), max_points)
        rec.log("world/replay", rr.Points3D(seg.points[idx], radii=0.0025), static=True)
        for n in range(data.num_events + 1):
            rec.set_time("grouping_event", sequence=n)
            lab = data.replay_sv_group(n)[seg.sv_labels[idx]]
            rec.log("world/replay", rr.Points3D.from_fields(colors=label_colors(lab)))
            rec.log("log/grouping", rr.TextLog(event_text(tr, n).replace("  \n", " | ")))
        if data.updates:  # scene updates (issue 10): pose iterations, loss/IoU, overlays
            from clutt3r_viewer.panels.update_sources import export_updates_rerun

            export_updates_rerun(rec, data, max_points)
    finally:
        rec.flush()
        rec.disconnect()
    tmp.replace(out)
    return out
