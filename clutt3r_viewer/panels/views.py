"""The title, the view selector and the selected view's image with its mask candidates."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from clutt3r_viewer.data import GREY, PALETTE, ViewerData
from clutt3r_viewer.layers import HIGHLIGHT
from clutt3r_viewer.panels.base import IMAGE_MAX_WIDTH, Change, Panel, downscale_step

if TYPE_CHECKING:
    import viser

    from clutt3r_viewer.app import Session

__all__ = ["ViewsPanel", "overlay_image", "view_label"]

NO_IMAGES = "_images unknown: pass the scene folder (`--scene`) to see them_"


def _outline(mask: np.ndarray) -> np.ndarray:
    """(H, W) bool -> boundary pixels (mask pixels with a 4-neighbour outside)."""
    m = mask
    inner = m.copy()
    inner[1:] &= m[:-1]
    inner[:-1] &= m[1:]
    inner[:, 1:] &= m[:, :-1]
    inner[:, :-1] &= m[:, 1:]
    return m & ~inner


def overlay_image(data: ViewerData, vi: int, selected: int = -1, max_width: int = IMAGE_MAX_WIDTH) -> np.ndarray | None:
    """The image of view ``vi`` with its mask candidates overlaid, downscaled to ``max_width``.

    Leaves are tinted with their instance colour (grey when in none), parents are outlined
    in white, background masks are hatched dark; the selected node is filled yellow.
    Returns None when the scene's images are unknown.
    """
    if not data.views:
        return None
    view = data.views[vi]
    s = downscale_step(view.camera.width, max_width)
    img = view.rgb[::s, ::s].astype(np.float32)
    nodes = data.view_nodes(vi)
    if view.masks is None or len(nodes) == 0:
        return img.astype(np.uint8)
    tr = data.trace
    stack = {int(i): data.node_mask(int(i))[::s, ::s] for i in nodes}
    # large masks first so that small ones stay visible on top
    order = sorted(stack, key=lambda i: -int(stack[i].sum()))
    for i in order:
        m = stack[i]
        if tr.nodes.background[i]:
            hatch = m & ((np.add.outer(np.arange(m.shape[0]), np.arange(m.shape[1])) // 4) % 4 == 0)
            img[hatch] *= 0.7
        elif tr.nodes.is_leaf[i] or data.substituted[i]:
            inst = data.node_instance[i]
            col = PALETTE[inst % len(PALETTE)] if inst >= 0 else GREY
            img[m] = 0.55 * img[m] + 0.45 * col
    for i in order:
        if not tr.nodes.is_leaf[i]:
            img[_outline(stack[i])] = 255
    if selected in stack:
        m = stack[selected]
        img[~m] *= 0.45  # dim the rest so the selection reads at a glance, whatever its colour
        img[m] = 0.4 * img[m] + 0.6 * HIGHLIGHT
        img[_outline(m)] = (0, 0, 0)
    return np.clip(img, 0, 255).astype(np.uint8)


def view_label(data: ViewerData, vi: int) -> str:
    return f"{vi}: frame {int(data.trace.frames[vi])}"


class ViewsPanel(Panel):
    """Above the tabs: what the run is, which view is selected, and that view's masks."""

    tab = None
    title: "viser.GuiMarkdownHandle"
    view: "viser.GuiDropdownHandle[str]"
    image: "viser.GuiImageHandle | None" = None

    def build(self, s: "Session") -> None:
        d = s.app.data
        gui = s.client.gui
        seg, tr = d.seg, d.trace
        self.title = gui.add_markdown(
            f"**{seg.scene_name or 'scene'}** — {seg.num_instances} instances, {len(seg.points):,} points, "
            f"{len(tr.frames)} views, {int(tr.nodes.is_leaf.sum())} leaves, embedder `{tr.embedder}`"
        )
        with gui.add_folder("View"):
            opts = [view_label(d, i) for i in range(len(tr.frames))]
            self.view = gui.add_dropdown("View", opts or ["none"], initial_value=(opts or ["none"])[0])
            self.view.on_update(lambda ev: s.select_view(int(self.view.value.split(":")[0])) if opts else None)
            img = overlay_image(d, s.state.view)
            if img is not None:
                self.image = gui.add_image(img, label="masks (leaf tint = instance, white = parent, yellow = selected)",
                                           format="jpeg", jpeg_quality=80)
            else:
                gui.add_markdown(s.app.no_images_text or NO_IMAGES)

    def refresh(self, s: "Session", change: Change) -> None:
        if change & Change.VIEW and len(s.app.data.trace.frames):
            label = view_label(s.app.data, s.state.view)
            if self.view.value != label:
                self.view.value = label
        if change & (Change.VIEW | Change.NODE) and self.image is not None:
            self.image.image = overlay_image(s.app.data, s.state.view, s.state.node)
