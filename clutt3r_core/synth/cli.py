"""``clutt3r synth``: generate synthetic cluttered-tabletop scenes (tyro builds the CLI from the signature)."""

from __future__ import annotations

from pathlib import Path
from typing import Literal


def synth_command(
    out: Path,
    seed: int = 0,
    preset: Literal["easy", "intermediate", "hard"] = "easy",
    views: int = 8,
    mask_noise: Literal["clean", "grounded-sam-like", "harsh"] = "grounded-sam-like",
    depth_noise: Literal["none", "realsense"] = "none",
    prepost: bool = False,
    width: int = 640,
    height: int = 480,
    tray: bool | None = None,
    n_objects: int | None = None,
    count: int = 1,
    contact_sheet: bool = True,
) -> None:
    """Generate synthetic cluttered-tabletop scenes in the sample layout (offline, CPU only).

    YCB household meshes are dropped into a pile with pybullet, ray-cast from `views`
    cameras around the pile (RGB, depth, ground-truth instance maps), and given noisy
    Grounded-SAM-like mask candidates. The folder loads with the same reader as real scenes.

    Args:
        out: output folder (one scene), or parent folder of `scene_NNNN/` when count > 1.
        seed: random seed; the same seed gives identical files.
        preset: clutter level: easy (6 objects), intermediate (10), hard (15, in a tray).
        views: number of initial views.
        mask_noise: mask-candidate error model.
        depth_noise: depth-sensor noise (realsense: disparity noise, holes at edges and grazing angles).
        prepost: also remove one object, push a neighbour and render one post-interaction view.
        width: image width in pixels.
        height: image height in pixels.
        tray: put the pile in a tray (default: as the preset says).
        n_objects: override the preset's object count.
        count: number of scenes (seeds seed, seed+1, ...).
        contact_sheet: write contact_sheet.png into each scene folder.
    """
    from clutt3r_core.synth.generator import SynthConfig, generate, write_synth_scene

    out = Path(out)
    for i in range(count):
        cfg = SynthConfig(seed=seed + i, preset=preset, views=views, width=width, height=height,
                          mask_noise=mask_noise, depth_noise=depth_noise, prepost=prepost, tray=tray,
                          n_objects=n_objects)
        res = generate(cfg, progress=True)
        folder = out if count == 1 else out / f"scene_{seed + i:04d}"
        write_synth_scene(res.scene, folder, info=res.info, contact_sheet=contact_sheet)
        info = res.info
        msg = (f"{folder}: {len(info.object_keys)} objects, {len(res.scene.views)} views, "
               f"mean occlusion {info.mean_occlusion:.1%}, generated in {info.seconds['total']:.1f} s")
        if info.interaction is not None:
            msg += (f"; removed object {info.interaction.removed_object}, "
                    f"displaced object {info.interaction.displaced_object}")
        print(msg)
