"""The Tree tab: the selected view's containment forest drawn as a tree (``tree_image``: a
thumbnail of each mask over its image crop, edges parent to child, the role as the colour of
the frame, the final instance), one button per mask to select it, and the selected node."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from clutt3r_viewer.data import GREY, PALETTE, ViewerData, node_label
from clutt3r_viewer.panels.base import IMAGE_MAX_WIDTH, Change, Panel

if TYPE_CHECKING:
    import viser

    from clutt3r_viewer.app import Session

__all__ = ["TreePanel", "tree_order", "node_kind", "tree_button_label", "tree_image", "ROLE_COLOURS"]

ROLE_COLOURS = {  # frame colour of a node in the drawn tree
    "leaf": (40, 170, 70), "parent": (255, 255, 255), "residual": (230, 160, 0), "substituted": (200, 60, 200),
    "replaced": (150, 150, 150), "background": (60, 60, 60),
}
THUMB = 44  # thumbnail side, pixels
ROW = THUMB + 8
INDENT = 28

LEGEND = ("  \nroles: leaf, parent, residual (alone after grouping), substituted (parent standing in for "
          "its residual leaves), replaced, background; → final instance")


def tree_order(data: ViewerData, vi: int) -> list[tuple[int, int]]:
    """(node, depth) of view vi in depth-first order, children by mask id."""
    n = data.trace.nodes
    nodes = data.view_nodes(vi)
    children: dict[int, list[int]] = {int(i): [] for i in nodes}
    roots = []
    for i in nodes:
        p = int(n.parent[i])
        (children[p] if p >= 0 else roots).append(int(i))
    out: list[tuple[int, int]] = []

    def walk(i: int, d: int) -> None:
        out.append((i, d))
        for c in sorted(children[i], key=lambda j: int(n.mask_id[j])):
            walk(c, d + 1)

    for r in sorted(roots, key=lambda j: int(n.mask_id[j])):
        walk(r, 0)
    return out


def node_kind(data: ViewerData, i: int) -> str:
    """Short role of node i: background / substituted / replaced / residual / leaf / parent."""
    n = data.trace.nodes
    if n.background[i]:
        return "background"
    if data.substituted[i]:
        return "substituted"
    if data.replaced[i]:
        return "replaced"
    if data.residual[i]:
        return "residual"
    return "leaf" if n.is_leaf[i] else "parent"


def tree_button_label(data: ViewerData, i: int, depth: int) -> str:
    inst = int(data.node_instance[i])
    tail = f" → I{inst}" if inst >= 0 else ""
    indent = "\u2003" * depth + ("└ " if depth else "")  # em spaces: HTML collapses ordinary leading spaces
    return f"{indent}M{int(data.trace.nodes.mask_id[i])} {node_kind(data, i)}{tail}"


def tree_image(data: ViewerData, vi: int, selected: int = -1, width: int = IMAGE_MAX_WIDTH) -> np.ndarray | None:
    """(H, width, 3) uint8 drawing of view ``vi``'s containment forest, one row per mask in
    depth-first order: edges from each parent down to its children, each node a thumbnail
    of its mask over the image crop (framed in its role's colour, ``ROLE_COLOURS``), and
    ``M<id> <role>`` and ``-> I<instance>`` in the instance's colour. The selected node's row is
    highlighted. None when the images are unknown."""
    from PIL import Image, ImageDraw

    order = tree_order(data, vi) if len(data.trace.frames) else []
    if not data.views or not order:
        return None
    rgb = data.views[vi].rgb
    h = ROW * len(order) + 4
    img = Image.new("RGB", (width, h), (250, 250, 250))
    dr = ImageDraw.Draw(img)
    row = {i: r for r, (i, _) in enumerate(order)}
    depth = dict(order)
    n = data.trace.nodes
    x_of = lambda i: 4 + depth[i] * INDENT  # noqa: E731
    for i, _ in order:  # edges first, under the thumbnails
        p = int(n.parent[i])
        if p in row:
            px, py = x_of(p) + THUMB // 2, 2 + row[p] * ROW + THUMB
            cy = 2 + row[i] * ROW + THUMB // 2
            dr.line([(px, py), (px, cy), (x_of(i), cy)], fill=(120, 120, 120), width=2)
    for i, _ in order:
        y0 = 2 + row[i] * ROW
        if i == selected:
            dr.rectangle([0, y0 - 2, width - 1, y0 + THUMB + 2], fill=(255, 236, 150))
        m = data.node_mask(i)
        if m is not None and m.any():
            ys, xs = np.nonzero(m)
            pad = 4
            y1, y2 = max(int(ys.min()) - pad, 0), min(int(ys.max()) + pad + 1, m.shape[0])
            x1, x2 = max(int(xs.min()) - pad, 0), min(int(xs.max()) + pad + 1, m.shape[1])
            crop = rgb[y1:y2, x1:x2].astype(np.float32)
            mk = m[y1:y2, x1:x2]
            crop[~mk] *= 0.35  # the mask bright, the rest of the crop dimmed
            th = Image.fromarray(crop.astype(np.uint8))
            th.thumbnail((THUMB - 4, THUMB - 4))
        else:
            th = Image.new("RGB", (THUMB - 4, THUMB - 4), (200, 200, 200))
        x0 = x_of(i)
        dr.rectangle([x0, y0, x0 + THUMB - 1, y0 + THUMB - 1], fill=(0, 0, 0), outline=ROLE_COLOURS[node_kind(data, i)],
                     width=2)
        img.paste(th, (x0 + 2 + (THUMB - 4 - th.width) // 2, y0 + 2 + (THUMB - 4 - th.height) // 2))
        inst = int(data.node_instance[i])
        col = tuple(int(c) for c in (PALETTE[inst % len(PALETTE)] if inst >= 0 else GREY))
        text = f"M{int(n.mask_id[i])} {node_kind(data, i)}"
        dr.text((x0 + THUMB + 6, y0 + 8), text, fill=(20, 20, 20))
        dr.text((x0 + THUMB + 6, y0 + 24), f"-> I{inst}" if inst >= 0 else "-> no instance", fill=col if inst >= 0
                else (110, 110, 110))
    return np.asarray(img)


class TreePanel(Panel):
    tab = "Tree"
    legend: "viser.GuiMarkdownHandle"
    clear: "viser.GuiButtonHandle"
    node: "viser.GuiMarkdownHandle"
    drawing: "viser.GuiImageHandle | None" = None
    folder: "viser.GuiFolderHandle | None" = None
    buttons: "dict[int, viser.GuiButtonHandle]"  # node index -> its button in the current tree

    def build(self, s: "Session") -> None:
        gui = s.client.gui
        self.buttons = {}
        self.legend = gui.add_markdown("")
        self.clear = gui.add_button("Clear selection")
        self.clear.on_click(lambda ev: s.select_node(-1))
        self.node = gui.add_markdown("")
        img = tree_image(s.app.data, s.state.view)
        if img is not None:
            self.drawing = gui.add_image(img, label="the tree (frame colour = role; → final instance)",
                                         format="png")
        self._rebuild(s, in_tab=True)

    def refresh(self, s: "Session", change: Change) -> None:
        if change & Change.VIEW:
            self._rebuild(s)
        elif change & Change.NODE:
            self._node_text(s)
        if change & (Change.VIEW | Change.NODE) and self.drawing is not None:
            img = tree_image(s.app.data, s.state.view, s.state.node)
            if img is not None:
                self.drawing.image = img

    def _rebuild(self, s: "Session", in_tab: bool = False) -> None:
        d = s.app.data
        vi = s.state.view
        gui = s.client.gui
        order = tree_order(d, vi) if len(d.trace.frames) else []
        n = d.trace.nodes
        dropped = d.trace.trees[vi].dropped_ids.tolist() if vi < len(d.trace.trees) else []
        frame = int(d.trace.frames[vi]) if len(d.trace.frames) else -1
        self.legend.content = (f"**frame {frame}**: {len(order)} masks, {int(n.is_leaf[d.view_nodes(vi)].sum())} leaves"
                               + (f", dropped (too small): {dropped}" if dropped else "") + LEGEND)
        if self.folder is not None:
            self.folder.remove()
        self.buttons = {}
        title, at = f"Tree of frame {frame}", self.legend.order + 0.5  # right after the legend
        if in_tab:  # building: already inside this tab (a tab cannot be entered twice)
            self.folder = gui.add_folder(title, order=at)
        else:
            assert self.tab_handle is not None
            with self.tab_handle:
                self.folder = gui.add_folder(title, order=at)
        with self.folder:
            for i, depth in order:
                b = gui.add_button(tree_button_label(d, i, depth), color=None)
                b.on_click(lambda ev, i=i: s.select_node(i))
                self.buttons[i] = b
        self._node_text(s)

    def _node_text(self, s: "Session") -> None:
        d = s.app.data
        i = s.state.node
        if i < 0:
            self.node.content = "_click a node to highlight its mask and its super-voxels_"
            return
        tr = d.trace
        c = d.node_centroid[i]
        grp = int(d.node_group[i])
        nsv = int((tr.occupancy[i] > 0).sum())
        self.node.content = (
            f"**{node_label(tr, i)}** ({node_kind(d, i)})  \n"
            f"area {int(d.node_mask(i).sum()) if d.views else '?'} px, {nsv} super-voxels, "
            f"group {grp if grp >= 0 else '-'} (size {len(tr.grouping.groups[grp]) if grp >= 0 else 0}), "
            f"instance {int(d.node_instance[i]) if d.node_instance[i] >= 0 else '-'}  \n"
            f"centroid {np.round(c, 3).tolist() if np.isfinite(c).all() else '-'} m"
        )
