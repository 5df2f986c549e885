"""The Leaf graph tab: cross-view leaf edges (S_spatial or S_semantic above a threshold) and a leaf's neighbours."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from clutt3r_viewer.data import ViewerData, node_label, ramp_colors
from clutt3r_viewer.panels.base import Change, Panel
from clutt3r_viewer.state import SessionState

if TYPE_CHECKING:
    import viser

    from clutt3r_viewer.app import Session

__all__ = ["LeafGraphPanel", "edge_selection"]

NO_LEAF = "_select a leaf in the Tree tab to list its neighbours_"


def edge_selection(data: ViewerData, state: SessionState) -> np.ndarray:
    """Indices into data.edges shown now (weight >= threshold, both centroids known)."""
    d = data
    w = d.edge_spatial if state.edge_weight == "spatial" else d.edge_semantic
    ok = np.nan_to_num(w, nan=-np.inf) >= state.edge_threshold
    ok &= np.isfinite(d.node_centroid[d.edges[:, 0], 0]) & np.isfinite(d.node_centroid[d.edges[:, 1], 0])
    if state.node >= 0:
        # with a leaf selected, only its edges: a readable star instead of a hairball
        ok &= (d.edges[:, 0] == state.node) | (d.edges[:, 1] == state.node)
    return np.flatnonzero(ok)


class LeafGraphPanel(Panel):
    tab = "Leaf graph"
    show: "viser.GuiCheckboxHandle"
    weight: "viser.GuiDropdownHandle[str]"
    threshold: "viser.GuiSliderHandle[float]"
    summary: "viser.GuiMarkdownHandle"
    neighbours: "viser.GuiMarkdownHandle"
    edges: "viser.LineSegmentsHandle | None" = None

    def build(self, s: "Session") -> None:
        gui = s.client.gui
        st = s.state
        self.show = gui.add_checkbox("Show edges", st.show_edges)
        self.show.on_update(lambda ev: self.set_edges(s, show=self.show.value))
        self.weight = gui.add_dropdown("Weight", ("spatial", "semantic"), initial_value=st.edge_weight)
        self.weight.on_update(lambda ev: self.set_edges(s, weight=self.weight.value))
        self.threshold = gui.add_slider("Threshold", 0.0, 1.0, 0.01, st.edge_threshold)
        self.threshold.on_update(lambda ev: self.set_edges(s, threshold=self.threshold.value))
        self.summary = gui.add_markdown("")
        self.neighbours = gui.add_markdown(NO_LEAF)
        self._draw(s)

    def set_edges(self, s: "Session", show: bool | None = None, weight: str | None = None,
                  threshold: float | None = None) -> None:
        with s.lock:
            if show is not None:
                s.state.show_edges = show
            if weight is not None:
                s.state.edge_weight = weight
            if threshold is not None:
                s.state.edge_threshold = float(threshold)
            self._draw(s)

    def refresh(self, s: "Session", change: Change) -> None:
        if change & (Change.NODE | Change.VIEW):
            self._neighbour_table(s)
            self._draw(s)

    def _neighbour_table(self, s: "Session") -> None:
        d = s.app.data
        i = s.state.node
        if i < 0 or not d.trace.nodes.is_leaf[i]:
            self.neighbours.content = NO_LEAF
            return
        nb = d.neighbours(i)
        lines = [f"**neighbours of {node_label(d.trace, i)}** ({len(nb)})", "",
                 "| leaf | S_spat | S_sem | same group |", "|---|---|---|---|"]
        for j, sp, se in nb[:15]:
            same = "yes" if d.node_group[j] >= 0 and d.node_group[j] == d.node_group[i] else ""
            lines.append(f"| {node_label(d.trace, j)} | {sp:.3f} | {se:.3f} | {same} |")
        self.neighbours.content = "\n".join(lines)

    def _draw(self, s: "Session") -> None:
        d = s.app.data
        st = s.state
        sel = edge_selection(d, st) if st.show_edges else np.zeros(0, np.int64)
        w = d.edge_spatial if st.edge_weight == "spatial" else d.edge_semantic
        self.summary.content = (f"{len(sel)} of {len(d.edges)} edges shown ({st.edge_weight} ≥ {st.edge_threshold:.2f}); "
                                "colour: blue = threshold … red = 1")
        if len(sel) == 0:
            if self.edges is not None:
                self.edges.visible = False
            return
        pts = d.node_centroid[d.edges[sel]].astype(np.float32)
        col = ramp_colors(w[sel], st.edge_threshold, 1.0)
        self.edges = s.client.scene.add_line_segments(
            "/leaf_graph", pts, np.repeat(col[:, None, :], 2, axis=1), thickness=2.0, thickness_units="screen")
