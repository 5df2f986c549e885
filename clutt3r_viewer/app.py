"""The viser application: one server, one ``Session`` per browser tab, each composed of panels.

Every tab gets its own GUI and scene nodes (``client.gui`` / ``client.scene``), so two
tabs select, recolour and replay independently. A ``Session`` builds the panels of
``clutt3r_viewer.panels.PANELS`` that the run has data for, keeps the tab's
``SessionState``, and broadcasts each change (``Change``) to every panel's ``refresh``
inside ``client.atomic()``. Static per-view nodes are built once and only their
visibility changes; recolouring assigns the point cloud handle's ``colors`` only, so
viser sends colours, not points.
"""

from __future__ import annotations

import threading
import time
from typing import Callable, TypeVar

import numpy as np

from clutt3r_viewer.assets import logo_data_uri
from clutt3r_viewer.camera import default_camera
from clutt3r_viewer.data import ViewerData, lod_indices
from clutt3r_viewer.events import EventSource, event_sources
from clutt3r_viewer.layers import COLOR_LAYERS, HIGHLIGHT, LayerInput, ghost_removed, layer_added_colors, layer_named
from clutt3r_viewer.panels import PANELS, Panel, ScenePanel
from clutt3r_viewer.panels.scene import LOD_OPTIONS
from clutt3r_viewer.scene_step import ShownScene, scene_step, shown_scene
from clutt3r_viewer.state import Change, SessionState

__all__ = ["SessionState", "Session", "ViewerApp", "LOD_OPTIONS"]

P = TypeVar("P", bound=Panel)


class Session:
    """GUI and scene of one client: its state and its panels."""

    def __init__(self, app: "ViewerApp", client) -> None:
        self.app = app
        self.client = client
        self.state = SessionState(lod=app.default_lod)
        self.lock = threading.RLock()
        self.closed = False
        self.built = False
        self.notification = None
        self.panels: list[Panel] = []
        self.lod_idx = np.zeros(0, np.int64)  # displayed points (level of detail), indices into seg.points
        self.colour_updates = 0
        self.build_seconds = 0.0

    def panel(self, cls: type[P]) -> P | None:
        """This tab's panel of class ``cls``, or None when the run has no data for it."""
        return next((p for p in self.panels if isinstance(p, cls)), None)

    # -- setup ------------------------------------------------------------------------

    def show_loading(self, text: str) -> None:
        if self.notification is None:
            self.notification = self.client.add_notification("Clutt3R", text, loading=True, with_close_button=False)
        else:
            self.notification.body = text

    def build(self) -> None:
        """Build this client's panels (once the data is ready)."""
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
            self.lod_idx = lod_indices(len(d.seg.points), LOD_OPTIONS[self.state.lod])
            with c.atomic():
                c.scene.set_up_direction("+z")
                tabs = None
                for cls in PANELS:
                    if not cls.available(self.app):
                        continue
                    p = cls()
                    if cls.tab is None:
                        p.build(self)
                    else:
                        if tabs is None:
                            tabs = c.gui.add_tab_group()
                        # panels with the same tab title share that tab
                        shared = next((q.tab_handle for q in self.panels if q.tab == cls.tab), None)
                        p.tab_handle = shared if shared is not None else tabs.add_tab(cls.tab)
                        with p.tab_handle:
                            p.build(self)
                    self.panels.append(p)
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
        pose = default_camera(self.app.data)
        cam.fov = pose.fov
        cam.position = pose.position
        cam.look_at = pose.look_at

    # -- colours ----------------------------------------------------------------------

    def replay_source(self) -> EventSource | None:
        """The event source the Replay panel steps through (by ``state.replay_source``; first as default)."""
        srcs = self.app.sources
        return next((s for s in srcs if s.name == self.state.replay_source), srcs[0] if srcs else None)

    def scene_step(self) -> int:
        """Updates applied to the scene this tab shows (the Updates tab's choice; 0 = the run)."""
        return scene_step(self.state.update, self.state.update_after, len(self.app.data.updates))

    def scene(self) -> ShownScene:
        """The scene this tab shows (``scene_step``) for its displayed points."""
        return shown_scene(self.app.data, self.scene_step(), self.lod_idx)

    def layer_input(self) -> LayerInput:
        step = self.scene_step()
        # after an update every layer colours the instances of that scene (removed ones -1, then
        # ghosted by point_colors); the run's (corrected) labels before any
        # (the loader's point_instance is SceneAfter's np.where(gone, -1, run_instance), made once:
        # this runs two or three times a recolour, 2.3 ms an np.where at 1M points)
        pi = self.app.data.updates[step - 1].point_instance if step > 0 else None  # None: an image-only frame
        inst = self.app.instance_labels() if pi is None else pi
        return LayerInput(data=self.app.data, idx=self.lod_idx, instance=inst,
                          scores=self.app.instance_scores(), replay=self.replay_source())

    def _layer(self, inp: LayerInput):
        layer = layer_named(self.state.color_mode)
        return layer if layer is not None and layer.available(inp, self.state) else COLOR_LAYERS[0]

    def point_colors(self) -> np.ndarray:
        """(n_displayed, 3) uint8 colours: the selected colour layer in the scene shown (removed
        instances ghosted), the selected node or instance highlighted."""
        inp = self.layer_input()
        st = self.state
        layer = self._layer(inp)
        col = layer.colors(inp, st)
        for p in self.panels:  # view-only overlays a panel keeps (the Edit tab's hidden instances)
            over = getattr(p, "overlay_colors", None)
            if over is not None:
                col = over(self, col)
        if layer.name not in ("replay", "update") and self.scene_step() > 0:  # "update" ghosts them itself
            col = ghost_removed(col, self.scene())
        return self._highlight(col, inp.instance[self.lod_idx], self.app.data.node_points(st.node)[self.lod_idx]
                               if st.node >= 0 else None)

    def added_colors(self) -> np.ndarray:
        """(A, 3) uint8 colours of the scene's added instances (``ShownScene.added_*``) in the
        selected colour layer, highlighted like the run's points."""
        inp = self.layer_input()
        sc = self.scene()
        col = layer_added_colors(self._layer(inp), inp, self.state, sc.added_instance, sc.added_colors)
        # a tree node is a mask of the initial views: never an added instance
        return self._highlight(col, sc.added_instance, np.zeros(len(col), bool) if self.state.node >= 0 else None)

    def _highlight(self, col: np.ndarray, inst: np.ndarray, node_sel: np.ndarray | None) -> np.ndarray:
        sel = node_sel
        if sel is None and self.state.instance >= 0:
            sel = np.asarray(inst) == self.state.instance
        if sel is None:
            return col
        col = (col * 0.35).astype(np.uint8)
        col[sel] = HIGHLIGHT
        return col

    def recolor(self) -> None:
        """Colour-only update of the displayed cloud."""
        p = self.panel(ScenePanel)
        if p is not None:
            p.recolor(self)

    def changed(self, change: Change) -> None:
        """Tell every panel that ``change`` happened (call with ``self.lock`` held)."""
        with self.client.atomic():
            for p in self.panels:
                p.refresh(self, change)

    # -- actions shared by several panels (viser's thread pool; one lock per session) -----

    def notify(self, title: str, body: str) -> None:
        self.client.add_notification(title, body, auto_close_seconds=5.0)

    def on_labels_changed(self) -> None:
        """The run's corrected labels changed (an edit in any tab): recolour, refresh lists."""
        with self.lock:
            if self.built and not self.closed:
                self.changed(Change.LABELS)

    def select_view(self, vi: int) -> None:
        with self.lock:
            d = self.app.data
            if not 0 <= vi < len(d.trace.frames) or (vi == self.state.view and self.state.node < 0):
                return
            self.state.view = vi
            self.state.node = -1
            self.changed(Change.VIEW | Change.NODE)

    def select_node(self, i: int) -> None:
        with self.lock:
            d = self.app.data
            change = Change.NODE
            if i >= 0 and int(d.trace.nodes.view[i]) != self.state.view:
                self.state.view = int(d.trace.nodes.view[i])
                change |= Change.VIEW
            self.state.node = int(i)
            if i >= 0 and self.state.instance >= 0:  # one highlight at a time
                self.state.instance = -1
                change |= Change.INSTANCE
            self.changed(change)

    def select_instance(self, k: int) -> None:
        """Select instance ``k`` of the scene shown (-1 = none): highlighted in every colour mode."""
        with self.lock:
            k = int(k)
            if k == self.state.instance:
                return
            change = Change.INSTANCE
            if k >= 0 and self.state.node >= 0:  # one highlight at a time
                self.state.node = -1
                change |= Change.NODE
            self.state.instance = k
            self.changed(change)

    def set_scene(self, update: int, after: bool | None = None, update_colours: bool = True) -> None:
        """Show the scene after (``after``, else just before) update ``update`` (-1 = the run),
        in the "update" colours when ``update_colours`` (the Updates tab), else in the current ones."""
        with self.lock:
            st = self.state
            after = st.update_after if after is None else bool(after)
            if update == st.update and after == st.update_after:
                return
            st.update, st.update_after = int(update), after
            if st.instance >= 0 and st.instance not in set(self.scene().present.tolist()):
                st.instance = -1  # removed (or not added yet) in the scene now shown
            if update_colours and any(f.point_instance is not None for f in self.app.data.updates):
                st.color_mode = "update"
            self.changed(Change.COLOUR | Change.SCENE | Change.INSTANCE)

    def set_color_mode(self, mode: str) -> None:
        with self.lock:
            if mode == self.state.color_mode:
                return
            self.state.color_mode = mode
            self.changed(Change.COLOUR)


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
        self.sources: list[EventSource] = []  # the run's event sources (Replay panel), shared by the tabs
        self.no_images_text: str | None = None  # why the run's images are missing, shown instead of them
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
            self.sources = event_sources(data)
            pose = default_camera(data)
            self.server.initial_camera.fov = pose.fov
            self.server.initial_camera.look_at = tuple(pose.look_at)
            self.server.initial_camera.position = tuple(pose.position)
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
