"""The viser application: one server, one ``Session`` (GUI + scene + selection) per browser tab.

Every tab gets its own GUI and scene nodes (``client.gui`` / ``client.scene``), so two
tabs select, recolour and replay independently. Static per-view nodes are built once
and only their visibility changes (inside ``client.atomic()``); recolouring assigns the
point cloud handle's ``colors`` only, so viser sends colours, not points.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass
from typing import Callable

import numpy as np

from clutt3r_viewer.assets import gripper_mesh, logo_data_uri
from clutt3r_viewer.data import (  # noqa: I001
    GREY,
    PALETTE,
    ViewerData,
    event_text,
    label_colors,
    lod_indices,
    node_label,
    ramp_colors,
)

__all__ = ["SessionState", "Session", "ViewerApp", "overlay_image", "LOD_OPTIONS", "COLOR_MODES"]

LOD_OPTIONS = {"50k": 50_000, "200k": 200_000, "1M": 1_000_000, "all": 0}
COLOR_MODES = ("instance", "rgb", "confidence", "replay")
HIGHLIGHT = np.array([255, 215, 0], np.uint8)
_IMAGE_MAX_WIDTH = 480  # GUI image width in pixels (the panel is ~350 px wide; 480 stays sharp on HiDPI)
_THUMB_MAX_WIDTH = 160  # frustum thumbnails: small, they are only a visual cue


def _downscale_step(width: int, max_width: int) -> int:
    return max(1, int(np.ceil(width / max_width)))


def _outline(mask: np.ndarray) -> np.ndarray:
    """(H, W) bool -> boundary pixels (mask pixels with a 4-neighbour outside)."""
    m = mask
    inner = m.copy()
    inner[1:] &= m[:-1]
    inner[:-1] &= m[1:]
    inner[:, 1:] &= m[:, :-1]
    inner[:, :-1] &= m[:, 1:]
    return m & ~inner


def overlay_image(data: ViewerData, vi: int, selected: int = -1, max_width: int = _IMAGE_MAX_WIDTH) -> np.ndarray | None:
    """The image of view ``vi`` with its mask candidates overlaid, downscaled to ``max_width``.

    Leaves are tinted with their instance colour (grey when in none), parents are outlined
    in white, background masks are hatched dark; the selected node is filled yellow.
    Returns None when the scene's images are unknown.
    """
    if not data.views:
        return None
    view = data.views[vi]
    s = _downscale_step(view.camera.width, max_width)
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
        o = _outline(m)
        img[o] = (0, 0, 0)
    return np.clip(img, 0, 255).astype(np.uint8)


def default_camera(data: ViewerData) -> tuple[np.ndarray, np.ndarray]:
    """(look_at, eye) in world metres: the objects' centre, seen obliquely (30 degrees up) from the
    side of the first view, 1.1x as far as the cameras, so the frustums above the pile stay out of the way."""
    seg = data.seg
    obj = seg.instance >= 0
    look = seg.points[obj].mean(axis=0).astype(np.float64) if obj.any() else data.centre
    if data.views:
        cams = np.stack([v.camera.T_world_camera[:3, 3] for v in data.views])
        dist = float(np.linalg.norm(cams - look, axis=1).mean()) * 1.1
        az_dir = cams[0, :2] - look[:2]
    else:
        dist = float(np.linalg.norm(np.ptp(seg.points, axis=0))) if len(seg.points) else 1.0
        az_dir = np.array([1.0, -1.0])
    az_dir = az_dir / max(float(np.linalg.norm(az_dir)), 1e-9)
    el = np.deg2rad(30.0)
    eye = look + dist * np.array([np.cos(el) * az_dir[0], np.cos(el) * az_dir[1], np.sin(el)])
    return look, eye


def _tree_order(data: ViewerData, vi: int) -> list[tuple[int, int]]:
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


@dataclass
class SessionState:
    """What one browser tab has selected (server side; tests assert on it)."""

    view: int = 0
    node: int = -1
    color_mode: str = "instance"
    event: int = 0
    edge_weight: str = "spatial"
    edge_threshold: float = 0.5
    show_edges: bool = False
    lod: str = "200k"
    query: str = ""
    query_best: int = -1
    grasp: int = -1
    update: int = -1
    playing: bool = False
    edit_instance: int = -1


class Session:
    """GUI and scene of one client."""

    def __init__(self, app: "ViewerApp", client) -> None:
        self.app = app
        self.client = client
        self.state = SessionState(lod=app.default_lod)
        self.lock = threading.RLock()
        self.closed = False
        self.built = False
        self.notification = None
        self.h: dict = {}
        self.tree_buttons: dict[int, object] = {}
        self.view_nodes: list = []
        self.frustums: list = []
        self.colour_updates = 0
        self.edit_panel = None

    # -- setup ------------------------------------------------------------------------

    def show_loading(self, text: str) -> None:
        if self.notification is None:
            self.notification = self.client.add_notification("Clutt3R", text, loading=True, with_close_button=False)
        else:
            self.notification.body = text

    def build(self) -> None:
        """Build this client's scene and GUI (once the data is ready)."""
        with self.lock:
            if self.built or self.closed:
                return
            t0 = time.perf_counter()
            d = self.app.data
            assert d is not None
            c = self.client
            if self.notification is not None:
                self.notification.title = "Clutt3R"
                self.notification.body = f"ready: {d.seg.num_instances} instances, {len(d.seg.points):,} points"
                self.notification.loading = False
                self.notification.with_close_button = True
                self.notification.auto_close_seconds = 4.0
            with c.atomic():
                c.scene.set_up_direction("+z")
                self._build_scene()
                self._build_gui()
            if self.notification is not None:  # this tab waited for a computation
                self._set_camera()
            self.build_seconds = time.perf_counter() - t0
            self.built = True

    def _set_camera(self) -> None:
        # Tabs that connect after the data is ready start at the server's initial camera
        # (set in ViewerApp.set_data). Tabs that were waiting for a background computation
        # already have a camera: move it, position first (setting look_at first on a fresh
        # client camera left the canvas empty in headless chromium).
        cam = self.client.camera
        if cam._state.update_timestamp == 0.0:
            return
        look, eye = default_camera(self.app.data)
        cam.position = eye
        cam.look_at = look

    def _build_scene(self) -> None:
        d = self.app.data
        sc = self.client.scene
        self.lod_idx = lod_indices(len(d.seg.points), LOD_OPTIONS[self.state.lod])
        self._add_cloud()
        ext = float(np.ptp(d.seg.points, axis=0).max()) if len(d.seg.points) else 1.0
        # small frustums: their image planes sit above the pile and must not hide it
        self.frustum_scale = float(np.clip(0.04 * ext, 0.02, 0.06))
        import viser.transforms as vtf

        for vi, v in enumerate(d.views):
            cam = v.camera
            s = _downscale_step(cam.width, _THUMB_MAX_WIDTH)
            fr = sc.add_camera_frustum(
                f"/cameras/view{vi}",
                fov=float(2 * np.arctan2(cam.height / 2, cam.fy)),
                aspect=cam.width / cam.height,
                scale=self.frustum_scale,
                thickness=2.0,
                thickness_units="screen",
                image=np.ascontiguousarray(v.rgb[::s, ::s]),
                jpeg_quality=70,
                wxyz=vtf.SO3.from_matrix(cam.T_world_camera[:3, :3]).wxyz,
                position=cam.T_world_camera[:3, 3],
                color=(255, 170, 0) if vi == self.state.view else (60, 60, 60),
            )
            fr.on_click(lambda ev, vi=vi: self.select_view(vi))
            self.frustums.append(fr)
        # per-view nodes, built once: the 3D centroids of that view's masks; toggled on view change
        for vi in range(len(d.trace.frames)):
            nodes = d.view_nodes(vi)
            ok = nodes[np.isfinite(d.node_centroid[nodes, 0])]
            pts = d.node_centroid[ok].astype(np.float32) if len(ok) else np.zeros((1, 3), np.float32)
            cols = label_colors(d.node_instance[ok]) if len(ok) else np.zeros((1, 3), np.uint8)
            self.view_nodes.append(
                sc.add_point_cloud(
                    f"/views/view{vi}/mask_centroids", pts, cols, point_size=self.frustum_scale * 0.25,
                    point_shape="circle", precision="float32", visible=vi == self.state.view,
                )
            )

    def _add_cloud(self) -> None:
        d = self.app.data
        centre = d.centre
        pts = (d.seg.points[self.lod_idx] - centre).astype(np.float32)
        self.cloud = self.client.scene.add_point_cloud(
            "/cloud", pts, self.point_colors(), point_size=self.app.point_size, point_shape="rounded",
            position=centre, precision="float16",
        )

    # -- colours ----------------------------------------------------------------------

    def point_colors(self) -> np.ndarray:
        """(n_displayed, 3) uint8 colours for the current mode and selection."""
        d = self.app.data
        st = self.state
        idx = self.lod_idx
        seg = d.seg
        if st.update >= 0 and st.update < len(d.updates) and d.updates[st.update].point_instance is not None:
            col = label_colors(d.updates[st.update].point_instance[idx])
        elif st.query_best >= 0 and self.query_scores is not None:
            inst = seg.instance[idx]
            sc = self.query_scores
            col = np.tile(GREY, (len(idx), 1))
            has = inst >= 0
            col[has] = ramp_colors(sc[inst[has]], float(sc.min()), float(sc.max()))
            col[inst == st.query_best] = HIGHLIGHT
        elif st.color_mode == "rgb":
            col = seg.colors[idx].copy()
        elif st.color_mode == "confidence":
            inst = self.app.instance_labels()[idx]
            scores = self.app.instance_scores()
            col = np.tile(GREY, (len(idx), 1))
            has = inst >= 0
            hi = float(scores.max()) if len(scores) else 1.0
            col[has] = ramp_colors(scores[inst[has]], 0.0, hi)
        elif st.color_mode == "replay":
            lab = d.replay_sv_group(st.event)[seg.sv_labels[idx]]
            col = label_colors(lab)
        else:
            col = label_colors(self.app.instance_labels()[idx])  # corrected labels when the run has edits
        if st.node >= 0:
            sel = d.node_points(st.node)[idx]
            col = (col * 0.35).astype(np.uint8)
            col[sel] = HIGHLIGHT
        return col

    query_scores: np.ndarray | None = None

    def recolor(self) -> None:
        """Colour-only update of the displayed cloud."""
        self.cloud.colors = self.point_colors()
        self.colour_updates += 1

    # -- GUI --------------------------------------------------------------------------

    def _build_gui(self) -> None:
        d = self.app.data
        gui = self.client.gui
        h = self.h
        seg = d.seg
        tr = d.trace
        h["title"] = gui.add_markdown(
            f"**{seg.scene_name or 'scene'}** — {seg.num_instances} instances, {len(seg.points):,} points, "
            f"{len(tr.frames)} views, {int(tr.nodes.is_leaf.sum())} leaves, embedder `{tr.embedder}`"
        )
        with gui.add_folder("View"):
            h["view"] = gui.add_dropdown(
                "View", [f"{i}: frame {int(f)}" for i, f in enumerate(tr.frames)],
                initial_value=f"0: frame {int(tr.frames[0])}" if len(tr.frames) else None,
            )
            h["view"].on_update(lambda ev: self.select_view(int(h["view"].value.split(":")[0])))
            img = overlay_image(d, self.state.view) if d.views else None
            if img is not None:
                h["image"] = gui.add_image(img, label="masks (leaf tint = instance, white = parent, yellow = selected)",
                                           format="jpeg", jpeg_quality=80)
            else:
                h["image"] = None
                gui.add_markdown("_images unknown: pass the scene folder (`--scene`) to see them_")
        tabs = gui.add_tab_group()
        with tabs.add_tab("Scene"):
            h["color"] = gui.add_dropdown("Colour", COLOR_MODES, initial_value=self.state.color_mode)
            h["color"].on_update(lambda ev: self.set_color_mode(h["color"].value))
            h["lod"] = gui.add_dropdown("Max points", tuple(LOD_OPTIONS), initial_value=self.state.lod,
                                        hint="level of detail: points sent to this tab")
            h["lod"].on_update(lambda ev: self.set_lod(h["lod"].value))
            h["size"] = gui.add_slider("Point size (mm)", 1.0, 20.0, 0.5, self.app.point_size * 1000)
            h["size"].on_update(lambda ev: setattr(self.cloud, "point_size", h["size"].value / 1000))
            h["frustums"] = gui.add_checkbox("Cameras", True)
            h["frustums"].on_update(lambda ev: self._toggle_frustums(h["frustums"].value))
            h["instances"] = gui.add_markdown(self._instances_md())
        with tabs.add_tab("Tree") as tree_tab:
            h["tree_tab"] = tree_tab
            h["tree_md"] = gui.add_markdown("")
            h["clear"] = gui.add_button("Clear selection")
            h["clear"].on_click(lambda ev: self.select_node(-1))
            h["tree_folder"] = None
            h["node_md"] = gui.add_markdown("")
        with tabs.add_tab("Leaf graph"):
            h["edges_on"] = gui.add_checkbox("Show edges", self.state.show_edges)
            h["edges_on"].on_update(lambda ev: self.set_edges(show=h["edges_on"].value))
            h["edge_w"] = gui.add_dropdown("Weight", ("spatial", "semantic"), initial_value=self.state.edge_weight)
            h["edge_w"].on_update(lambda ev: self.set_edges(weight=h["edge_w"].value))
            h["edge_t"] = gui.add_slider("Threshold", 0.0, 1.0, 0.01, self.state.edge_threshold)
            h["edge_t"].on_update(lambda ev: self.set_edges(threshold=h["edge_t"].value))
            h["edges_md"] = gui.add_markdown("")
            h["nbr_md"] = gui.add_markdown("_select a leaf in the Tree tab to list its neighbours_")
        with tabs.add_tab("Replay"):
            ne = d.num_events
            h["event"] = gui.add_slider("Event", 0, max(ne, 1), 1, 0, disabled=ne == 0)
            h["event"].on_update(lambda ev: self.set_event(int(h["event"].value)))
            h["play"] = gui.add_button("Play", icon=None)
            h["play"].on_click(lambda ev: self.toggle_play())
            h["event_md"] = gui.add_markdown(event_text(tr, 0))
            h["groups_md"] = gui.add_markdown("")
        if self.app.text_embedder is not None:
            with tabs.add_tab("Query"):
                h["query"] = gui.add_text("Query", "")
                h["query_go"] = gui.add_button("Find")
                h["query_go"].on_click(lambda ev: self.run_query(h["query"].value))
                h["query"].on_update(lambda ev: self.run_query(h["query"].value))
                h["query_md"] = gui.add_markdown(f"_text embedder: `{self.app.text_embedder.name}`_")
        if self.app.annotations is not None:
            with tabs.add_tab("Edit"):
                from clutt3r_viewer.edit import EditPanel

                self.edit_panel = EditPanel(self)
        if d.grasps is not None:
            with tabs.add_tab("Grasps"):
                self._build_grasps()
        if d.updates:
            with tabs.add_tab("Updates"):
                h["update"] = gui.add_slider("Update frame", -1, len(d.updates) - 1, 1, -1)
                h["update"].on_update(lambda ev: self.set_update(int(h["update"].value)))
                h["update_md"] = gui.add_markdown("_-1 = the initial segmentation_")
                h["update_img"] = None
        self._refresh_tree()
        self._refresh_edges()
        self._refresh_replay_text()

    def _instances_md(self) -> str:
        d = self.app.data
        seg = d.seg
        ann = self.app.annotations
        if ann is not None and ann.num_ops:  # corrected: masks are those of the original instance
            lab = ann.current
            lines = ["| inst | conf | category | points |", "|---|---|---|---|"]
            npts = lab.point_counts()
            for k in lab.alive:
                lines.append(f"| I{k} | {lab.scores[k]:.2f} | {lab.categories[k]} | {int(npts[k])} |")
            return "\n".join(lines)
        lines = ["| inst | conf | masks | points |", "|---|---|---|---|"]
        npts = np.bincount(seg.instance[seg.instance >= 0], minlength=seg.num_instances)
        for k in range(seg.num_instances):
            lines.append(f"| I{k} | {seg.scores[k]:.2f} | {len(seg.instance_nodes(k))} | {int(npts[k])} |")
        return "\n".join(lines)

    def notify(self, title: str, body: str) -> None:
        self.client.add_notification(title, body, auto_close_seconds=5.0)

    def on_labels_changed(self) -> None:
        """The run's corrected labels changed (an edit in any tab): recolour, refresh lists."""
        with self.lock:
            if not self.built or self.closed:
                return
            with self.client.atomic():
                self.recolor()
                self.h["instances"].content = self._instances_md()
                if self.edit_panel is not None:
                    self.edit_panel.refresh()

    def _toggle_frustums(self, on: bool) -> None:
        with self.client.atomic():
            for f in self.frustums:
                f.visible = on

    # -- actions (each runs in viser's thread pool; one lock per session) ---------------

    def select_view(self, vi: int) -> None:
        with self.lock:
            d = self.app.data
            if not 0 <= vi < len(d.trace.frames) or (vi == self.state.view and self.state.node < 0):
                return
            self.state.view = vi
            self.state.node = -1
            with self.client.atomic():
                for k, n in enumerate(self.view_nodes):
                    n.visible = k == vi
                for k, f in enumerate(self.frustums):
                    f.color = (255, 170, 0) if k == vi else (60, 60, 60)
                label = f"{vi}: frame {int(d.trace.frames[vi])}"
                if self.h["view"].value != label:
                    self.h["view"].value = label
                self._refresh_image()
                self._refresh_tree()
                self.recolor()

    def select_node(self, i: int) -> None:
        with self.lock:
            d = self.app.data
            if i >= 0 and int(d.trace.nodes.view[i]) != self.state.view:
                self.state.view = int(d.trace.nodes.view[i])
            self.state.node = int(i)
            with self.client.atomic():
                self._refresh_image()
                self._refresh_node_md()
                self._refresh_neighbours()
                if self.edit_panel is not None:
                    self.edit_panel.select_node(int(i))
                self.recolor()

    def set_color_mode(self, mode: str) -> None:
        with self.lock:
            self.state.color_mode = mode
            self.state.query_best = -1
            self.recolor()

    def set_lod(self, lod: str) -> None:
        with self.lock:
            self.state.lod = lod
            self.lod_idx = lod_indices(len(self.app.data.seg.points), LOD_OPTIONS[lod])
            self._add_cloud()  # same name: replaces the node (new points)

    def set_edges(self, show: bool | None = None, weight: str | None = None, threshold: float | None = None) -> None:
        with self.lock:
            if show is not None:
                self.state.show_edges = show
            if weight is not None:
                self.state.edge_weight = weight
            if threshold is not None:
                self.state.edge_threshold = float(threshold)
            self._refresh_edges()

    def set_event(self, n: int) -> None:
        with self.lock:
            self.state.event = int(n)
            self.state.color_mode = "replay"
            self.state.query_best = -1
            with self.client.atomic():
                if self.h["color"].value != "replay":
                    self.h["color"].value = "replay"
                if int(self.h["event"].value) != n:
                    self.h["event"].value = n
                self._refresh_replay_text()
                self.recolor()

    def toggle_play(self) -> None:
        with self.lock:
            self.state.playing = not self.state.playing
            self.h["play"].label = "Pause" if self.state.playing else "Play"
            if self.state.playing:
                if self.state.event >= self.app.data.num_events:
                    self.set_event(0)
                threading.Thread(target=self._play_loop, daemon=True).start()

    def _play_loop(self) -> None:
        while self.state.playing and not self.closed:
            time.sleep(self.app.play_interval)
            with self.lock:
                if not self.state.playing:
                    break
                n = self.state.event + 1
                if n > self.app.data.num_events:
                    self.state.playing = False
                    self.h["play"].label = "Play"
                    break
                self.set_event(n)

    def run_query(self, text: str) -> None:
        with self.lock:
            text = text.strip()
            self.state.query = text
            if not text:
                self.state.query_best = -1
                self.h["query_md"].content = "_empty query_"
                self.recolor()
                return
            emb = self.app.text_embedder.embed_text([text])[0]
            scores = self.app.data.instance_text_scores(emb)
            self.query_scores = scores
            if len(scores) == 0:
                self.state.query_best = -1
                self.h["query_md"].content = "_no instances_"
                self.recolor()
                return
            order = np.argsort(-scores)
            self.state.query_best = int(order[0])
            self.h["query_md"].content = "\n".join(
                [f"**{text}** → I{int(order[0])}", "", "| inst | score |", "|---|---|"]
                + [f"| I{int(k)} | {scores[k]:.3f} |" for k in order[:8]]
            )
            self.recolor()

    def set_update(self, u: int) -> None:
        with self.lock:
            self.state.update = int(u)
            d = self.app.data
            if 0 <= u < len(d.updates):
                upd = d.updates[u]
                self.h["update_md"].content = f"**frame {upd.frame}**  \n{upd.text}"
                if upd.rgb is not None:
                    s = _downscale_step(upd.rgb.shape[1], _IMAGE_MAX_WIDTH)
                    if self.h["update_img"] is None:
                        self.h["update_img"] = self.client.gui.add_image(upd.rgb[::s, ::s], format="jpeg")
                    else:
                        self.h["update_img"].image = upd.rgb[::s, ::s]
            else:
                self.h["update_md"].content = "_-1 = the initial segmentation_"
            self.recolor()

    # -- refreshers -------------------------------------------------------------------

    def _refresh_image(self) -> None:
        if self.h.get("image") is not None:
            self.h["image"].image = overlay_image(self.app.data, self.state.view, self.state.node)

    def _refresh_tree(self) -> None:
        d = self.app.data
        vi = self.state.view
        gui = self.client.gui
        old = self.h.get("tree_folder")
        order = _tree_order(d, vi)
        n = d.trace.nodes
        dropped = d.trace.trees[vi].dropped_ids.tolist() if vi < len(d.trace.trees) else []
        self.h["tree_md"].content = (
            f"**frame {int(d.trace.frames[vi])}**: {len(order)} masks, "
            f"{int(n.is_leaf[d.view_nodes(vi)].sum())} leaves"
            + (f", dropped (too small): {dropped}" if dropped else "")
            + "  \nroles: leaf, parent, residual (alone after grouping), substituted (parent standing in for "
            "its residual leaves), replaced, background; → final instance"
        )
        if old is not None:
            old.remove()
        self.tree_buttons = {}
        legend = self.h["tree_md"]  # the folder goes right after the legend, inside the Tree tab
        with self.h["tree_tab"]:
            folder = gui.add_folder(f"Tree of frame {int(d.trace.frames[vi])}", order=legend.order + 0.5)
        with folder:
            for i, depth in order:
                b = gui.add_button(tree_button_label(d, i, depth), color=None)
                b.on_click(lambda ev, i=i: self.select_node(i))
                self.tree_buttons[i] = b
        self.h["tree_folder"] = folder
        self._refresh_node_md()

    def _refresh_node_md(self) -> None:
        d = self.app.data
        i = self.state.node
        if i < 0:
            self.h["node_md"].content = "_click a node to highlight its mask and its super-voxels_"
            return
        tr = d.trace
        c = d.node_centroid[i]
        grp = int(d.node_group[i])
        nsv = int((tr.occupancy[i] > 0).sum())
        self.h["node_md"].content = (
            f"**{node_label(tr, i)}** ({node_kind(d, i)})  \n"
            f"area {int(d.node_mask(i).sum()) if d.views else '?'} px, {nsv} super-voxels, "
            f"group {grp if grp >= 0 else '-'} (size {len(tr.grouping.groups[grp]) if grp >= 0 else 0}), "
            f"instance {int(d.node_instance[i]) if d.node_instance[i] >= 0 else '-'}  \n"
            f"centroid {np.round(c, 3).tolist() if np.isfinite(c).all() else '-'} m"
        )

    def _refresh_neighbours(self) -> None:
        d = self.app.data
        i = self.state.node
        if i < 0 or not d.trace.nodes.is_leaf[i]:
            self.h["nbr_md"].content = "_select a leaf in the Tree tab to list its neighbours_"
        else:
            nb = d.neighbours(i)
            lines = [f"**neighbours of {node_label(d.trace, i)}** ({len(nb)})", "", "| leaf | S_spat | S_sem | same group |",
                     "|---|---|---|---|"]
            for j, sp, se in nb[:15]:
                same = "yes" if d.node_group[j] >= 0 and d.node_group[j] == d.node_group[i] else ""
                lines.append(f"| {node_label(d.trace, j)} | {sp:.3f} | {se:.3f} | {same} |")
            self.h["nbr_md"].content = "\n".join(lines)
        self._refresh_edges()

    def edge_selection(self) -> np.ndarray:
        """Indices into data.edges shown now (weight >= threshold, both centroids known)."""
        d = self.app.data
        w = d.edge_spatial if self.state.edge_weight == "spatial" else d.edge_semantic
        ok = np.nan_to_num(w, nan=-np.inf) >= self.state.edge_threshold
        ok &= np.isfinite(d.node_centroid[d.edges[:, 0], 0]) & np.isfinite(d.node_centroid[d.edges[:, 1], 0])
        if self.state.node >= 0:
            # with a leaf selected, only its edges: a readable star instead of a hairball
            ok &= (d.edges[:, 0] == self.state.node) | (d.edges[:, 1] == self.state.node)
        return np.flatnonzero(ok)

    def _refresh_edges(self) -> None:
        d = self.app.data
        sel = self.edge_selection() if self.state.show_edges else np.zeros(0, np.int64)
        w = d.edge_spatial if self.state.edge_weight == "spatial" else d.edge_semantic
        self.h["edges_md"].content = (
            f"{len(sel)} of {len(d.edges)} edges shown ({self.state.edge_weight} ≥ {self.state.edge_threshold:.2f}); "
            "colour: blue = threshold … red = 1"
        )
        sc = self.client.scene
        if len(sel) == 0:
            if self.h.get("edges") is not None:
                self.h["edges"].visible = False
            return
        pts = d.node_centroid[d.edges[sel]].astype(np.float32)
        col = ramp_colors(w[sel], self.state.edge_threshold, 1.0)
        self.h["edges"] = sc.add_line_segments(
            "/leaf_graph", pts, np.repeat(col[:, None, :], 2, axis=1), thickness=2.0, thickness_units="screen"
        )

    def _refresh_replay_text(self) -> None:
        d = self.app.data
        n = self.state.event
        self.h["event_md"].content = event_text(d.trace, n)
        self.h["groups_md"].content = (
            f"{d.replay_num_groups(n)} groups so far; colour = super-voxel vote of those groups "
            f"(final: {d.seg.num_instances} instances)"
        )

    def _build_grasps(self) -> None:
        d = self.app.data
        g = d.grasps
        gui = self.client.gui
        order = np.argsort(-g.scores)
        self.h["grasp_md"] = gui.add_markdown(f"{len(g.scores)} grasp candidates")
        self.h["grasp_dd"] = gui.add_dropdown(
            "Grasp", ["none"] + [f"{int(k)}: I{int(g.instance[k])} score {g.scores[k]:.2f}" for k in order[:50]],
            initial_value="none",
        )
        self.h["grasp_dd"].on_update(lambda ev: self.select_grasp(self.h["grasp_dd"].value))
        segs = np.concatenate([gripper_segments(g.poses[k], g.widths[k]) for k in range(len(g.scores))]) \
            if len(g.scores) else np.zeros((0, 2, 3), np.float32)
        if len(segs):
            col = np.repeat(ramp_colors(g.scores, float(g.scores.min()), float(g.scores.max())), 4, axis=0)
            self.client.scene.add_line_segments("/grasps/all", segs, np.repeat(col[:, None], 2, axis=1),
                                                thickness=1.5, thickness_units="screen")

    def select_grasp(self, value: str) -> None:
        with self.lock:
            g = self.app.data.grasps
            if value == "none":
                self.state.grasp = -1
                if self.h.get("grasp_sel") is not None:
                    self.h["grasp_sel"].visible = False
                return
            k = int(value.split(":")[0])
            self.state.grasp = k
            mesh = gripper_mesh(g.poses[k], g.widths[k])
            if mesh is not None:  # the gripper mesh of static/, fingers at this grasp's width
                self.h["grasp_sel"] = self.client.scene.add_mesh_simple(
                    "/grasps/selected", mesh[0], mesh[1], color=tuple(int(c) for c in HIGHLIGHT))
            else:
                self.h["grasp_sel"] = self.client.scene.add_line_segments(
                    "/grasps/selected", gripper_segments(g.poses[k], g.widths[k]), HIGHLIGHT, thickness=5.0,
                    thickness_units="screen")


def gripper_segments(T: np.ndarray, width: float, depth: float = 0.05) -> np.ndarray:
    """(4, 2, 3) float32 line segments of a parallel-jaw gripper at ``T_world_gripper``.

    Gripper frame: z = approach direction, x = closing direction; the fingertips are at the origin.
    """
    w = float(width) / 2
    local = np.array([
        [[-w, 0, 0], [w, 0, 0]],              # palm bar
        [[-w, 0, 0], [-w, 0, depth]],         # left finger
        [[w, 0, 0], [w, 0, depth]],           # right finger
        [[0, 0, 0], [0, 0, -depth]],          # wrist
    ], np.float64)
    local[..., 2] -= depth  # fingertips at the origin, palm behind them
    p = local.reshape(-1, 3) @ T[:3, :3].T + T[:3, 3]
    return p.reshape(4, 2, 3).astype(np.float32)


class ViewerApp:
    """A viser server showing one run to any number of tabs.

    ``data`` may arrive later (``set_data``), e.g. while a scene is being segmented;
    tabs that connect before see a progress notification.
    """

    def __init__(
        self,
        data: ViewerData | None = None,
        host: str = "127.0.0.1",
        port: int = 8080,
        text_embedder=None,
        lod: str = "200k",
        point_size: float = 0.006,
        play_interval: float = 0.4,
        verbose: bool = False,
    ) -> None:
        import viser

        self.data: ViewerData | None = None
        self.default_lod = lod
        self.point_size = point_size
        self.play_interval = play_interval
        self.text_embedder = text_embedder
        self.annotations = None  # clutt3r_core.annotations.Annotations of the run folder, when there is one
        self._edit_lock = threading.Lock()
        self.sessions: dict[int, Session] = {}
        self._status = "loading"
        self._lock = threading.Lock()
        self.server = viser.ViserServer(host=host, port=port, label="Clutt3R", verbose=verbose)
        logo = logo_data_uri()
        titlebar = None
        if logo is not None:
            titlebar = viser.theme.TitlebarConfig(
                buttons=None, image=viser.theme.TitlebarImage(image_url_light=logo, image_url_dark=None,
                                                              image_alt="Clutt3R", href=None))
        self.server.gui.configure_theme(titlebar_content=titlebar, control_width="large", show_share_button=False,
                                        brand_color=(230, 140, 20))
        self.server.scene.set_up_direction("+z")
        self.server.scene.world_axes.visible = False
        self.server.on_client_connect(self._on_connect)
        self.server.on_client_disconnect(self._on_disconnect)
        if data is not None:
            self.set_data(data)

    @property
    def port(self) -> int:
        return int(self.server.get_port())

    @property
    def url(self) -> str:
        return f"http://{self.server.get_host()}:{self.port}"

    def set_status(self, text: str) -> None:
        """Progress text shown to tabs while the data is not ready."""
        self._status = text
        for s in list(self.sessions.values()):
            if not s.built:
                s.show_loading(text)

    def set_data(self, data: ViewerData, annotations=None) -> None:
        """Show ``data``; ``annotations`` (the run's ``Annotations``) adds the Edit tab and corrected colours."""
        with self._lock:
            self.data = data
            self.annotations = annotations
            if self.text_embedder is not None and getattr(self.text_embedder, "dim", None) not in (None, data.trace.embeddings.shape[1]):
                self.text_embedder = None  # a text space that is not the masks' space cannot rank them
            look, eye = default_camera(data)
            self.server.initial_camera.look_at = tuple(look)
            self.server.initial_camera.position = tuple(eye)
            sessions = list(self.sessions.values())
        for s in sessions:
            s.build()

    def instance_labels(self) -> np.ndarray:
        """(N,) int32 instance per point shown: the corrected labelling when the run has corrections."""
        a = self.annotations
        return a.current.instance if a is not None else self.data.seg.instance

    def instance_scores(self) -> np.ndarray:
        a = self.annotations
        return a.current.scores if a is not None else self.data.seg.scores

    def edit_run(self, action, session: "Session | None" = None, select_new: bool = False) -> bool:
        """Apply ``action(annotations)`` (apply_op / undo / redo; logged and fsynced before it
        returns), save the snapshot and refresh every tab. Call without holding a session lock."""
        from clutt3r_viewer.edit import run_edit

        if self.annotations is None:
            return False
        with self._edit_lock:
            err = run_edit(self.annotations, action)
            n = self.annotations.current.num_instances
        if err is not None:
            if session is not None:
                session.notify("Edit refused", err)
            return False
        if select_new and session is not None:
            with session.lock:
                session.state.edit_instance = n - 1
        for s in list(self.sessions.values()):
            s.on_labels_changed()
        return True

    def _on_connect(self, client) -> None:
        s = Session(self, client)
        with self._lock:
            self.sessions[client.client_id] = s
            ready = self.data is not None
        if ready:
            s.build()
        else:
            s.show_loading(self._status)

    def _on_disconnect(self, client) -> None:
        s = self.sessions.pop(client.client_id, None)
        if s is not None:
            s.closed = True
            s.state.playing = False

    def wait_for_sessions(self, n: int = 1, timeout: float = 30.0, built: bool = True) -> list[Session]:
        """Block until ``n`` tabs are connected (and built); for tests and benchmarks."""
        t0 = time.time()
        while time.time() - t0 < timeout:
            ss = [s for s in list(self.sessions.values()) if s.built or not built]
            if len(ss) >= n:
                return ss
            time.sleep(0.05)
        raise TimeoutError(f"{n} viewer session(s) did not connect within {timeout} s")

    def stop(self) -> None:
        for s in list(self.sessions.values()):
            s.closed = True
            s.state.playing = False
        self.server.stop()
        if self.annotations is not None:
            self.annotations.close()  # every edit is already in the log; this releases its lock

    def compute_in_background(self, compute: Callable[[Callable[[str], None]], ViewerData]) -> threading.Thread:
        """Run ``compute(report)`` in a thread and show its data when done; ``report(text)`` updates the progress."""

        def run() -> None:
            t0 = time.time()
            stop = threading.Event()

            def ticker() -> None:
                while not stop.wait(1.0):
                    self.set_status(f"{self._status.split(' (')[0]} ({time.time() - t0:.0f} s)")

            threading.Thread(target=ticker, daemon=True).start()
            try:
                data = compute(self.set_status)
            except Exception as e:  # shown to the user in the page; the server keeps running
                stop.set()
                self.set_status(f"failed: {type(e).__name__}: {e}")
                raise
            stop.set()
            self.set_data(data)

        t = threading.Thread(target=run, daemon=True)
        t.start()
        return t
