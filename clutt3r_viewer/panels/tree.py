"""The Tree tab: the selected view's containment forest, one button per mask, and the selected node."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from clutt3r_viewer.data import ViewerData, node_label
from clutt3r_viewer.panels.base import Change, Panel

if TYPE_CHECKING:
    import viser

    from clutt3r_viewer.app import Session

__all__ = ["TreePanel", "tree_order", "node_kind", "tree_button_label"]

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


class TreePanel(Panel):
    tab = "Tree"
    legend: "viser.GuiMarkdownHandle"
    clear: "viser.GuiButtonHandle"
    node: "viser.GuiMarkdownHandle"
    folder: "viser.GuiFolderHandle | None" = None
    buttons: "dict[int, viser.GuiButtonHandle]"  # node index -> its button in the current tree

    def build(self, s: "Session") -> None:
        gui = s.client.gui
        self.buttons = {}
        self.legend = gui.add_markdown("")
        self.clear = gui.add_button("Clear selection")
        self.clear.on_click(lambda ev: s.select_node(-1))
        self.node = gui.add_markdown("")
        self._rebuild(s, in_tab=True)

    def refresh(self, s: "Session", change: Change) -> None:
        if change & Change.VIEW:
            self._rebuild(s)
        elif change & Change.NODE:
            self._node_text(s)

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
