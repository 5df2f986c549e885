"""The guided tour (issue 16): Previous / Next through the demo's story (``clutt3r_viewer.tour.STEPS``).

Each step drives the other panels through their own actions (``Session.select_view``,
``ReplayPanel.set_event``, ``QueryPanel.run_query``, ``GraspsPanel.plan_for``, ...), so it shows
exactly what a user clicking would see; then it sets the colour layer, moves this tab's camera
and opens the step's tab. "Explore freely" leaves the tour (the panels stay as they are);
"Resume" applies the current step again. "Download HTML" sends the run as a standalone page
(``export_html``).

viser 1.1 has no server-side call that selects a tab; the step opens its tab by clicking it in
the page, with a one-line script in an HTML element (``open_tab_html``). The tour panel is shown
for a run with a demo story (``clutt3r demo``, or ``RUN/demo.json``).
"""

from __future__ import annotations

import json
import threading
from typing import TYPE_CHECKING

from clutt3r_viewer.camera import CameraPose
from clutt3r_viewer.panels.base import Change, Panel
from clutt3r_viewer.tour import STEPS, TourStep, facts_of, focus_points, replay_event, step_camera, tree_node, tree_view

if TYPE_CHECKING:
    import viser

    from clutt3r_viewer.app import Session, ViewerApp

__all__ = ["TourPanel", "ShareHtmlPanel", "send_html", "attach_story", "story_of", "open_tab_html", "POSE_SOURCE", "GROUPING_SOURCE"]

GROUPING_SOURCE = "grouping"
POSE_SOURCE = "scene updates: pose iterations"


def story_of(app: "ViewerApp"):
    """The app's demo story (``attach_story``), else the run folder's ``demo.json``, else None."""
    st = getattr(app, "tour_story", None)
    if st is not None:
        return st
    run_dir = getattr(app.annotations, "run_dir", None)
    if run_dir is None:
        return None
    from clutt3r_core.demo import load_story

    try:
        st = load_story(run_dir)
    except Exception:  # noqa: BLE001  (a damaged story only hides the tour)
        return None
    app.tour_story = st
    if st is not None and st.complete:
        _attach_query(app, st)
    return st


def _attach_query(app: "ViewerApp", story) -> None:
    """Give the Query tab the demo's cached mask evidence (``RUN/query_cache.npz``), so the first
    query does not describe every mask again."""
    if story.query is None or app.data is None:
        return
    try:
        from clutt3r_core.query import RunQuery

        rq = RunQuery.open(story.run)
        app._run_query = RunQuery.from_evidence(app.data.seg, rq.grounder, rq.evidence)  # QueryPanel's cache
    except Exception:  # noqa: BLE001  (the Query tab then describes the masks itself)
        pass


def attach_story(app: "ViewerApp", story, failed: str = "") -> None:
    """Set (or complete) the app's demo story; tabs on a step that was waiting for it re-apply it."""
    if story.complete:
        _attach_query(app, story)
    app.tour_story = story
    app.tour_failed = failed
    for s in list(app.sessions.values()):
        p = s.panel(TourPanel) if s.built else None
        if p is not None:
            p.story_changed(s)


def open_tab_html(tab: str, nonce: int) -> str:
    """An invisible HTML element whose broken image runs one line of script: click the tab named
    ``tab``. ``nonce`` makes each step's element new, so the script runs again. The tabs react to
    pointer events (a bare ``element.click()`` does not switch them), so the script sends the
    sequence a mouse click makes."""
    label = json.dumps(tab).replace('"', "&quot;")
    js = ("var t=Array.from(document.querySelectorAll('[role=tab]')).find(function(b){return b.textContent.trim()==="
          + label + "});if(t&&t.getAttribute('aria-selected')!=='true'){['pointerdown','mousedown','pointerup',"
          "'mouseup','click'].forEach(function(n){var E=n.indexOf('pointer')==0?PointerEvent:MouseEvent;"
          "t.dispatchEvent(new E(n,{bubbles:true,cancelable:true,button:0,isPrimary:true,pointerId:1,view:window}))})}")
    return f'<img alt="" style="display:none" src="data:image/png;base64,{nonce}" onerror="{js}">'


class TourPanel(Panel):
    """Above the tabs (shown first): the step's title and sentences, Previous / Next, Explore / Resume."""

    tab = None
    folder: "viser.GuiFolderHandle"
    title: "viser.GuiMarkdownHandle"
    text: "viser.GuiMarkdownHandle"
    prev: "viser.GuiButtonHandle"
    next: "viser.GuiButtonHandle"
    explore: "viser.GuiButtonHandle"
    resume: "viser.GuiButtonHandle"
    download: "viser.GuiButtonHandle"
    tab_opener: "viser.GuiHtmlHandle"
    step: int = 0
    exploring: bool = False
    applied: int = 0  # steps applied (tests wait on it)
    camera: "CameraPose | None" = None  # the current step's camera
    before: "viser.PointCloudHandle | None" = None  # the pushed object where it was (pose step)

    @classmethod
    def available(cls, app: "ViewerApp") -> bool:
        return story_of(app) is not None

    def build(self, s: "Session") -> None:
        gui = s.client.gui
        self.folder = gui.add_folder("Guided tour", order=-1000.0)  # above the title and the views
        with self.folder:
            self.title = gui.add_markdown("")
            self.text = gui.add_markdown("")
            self.prev = gui.add_button("Previous", icon=None)
            self.next = gui.add_button("Next")
            self.explore = gui.add_button("Explore freely", hint="leave the tour; Resume comes back to this step")
            self.resume = gui.add_button("Resume", visible=False)
            self.download = gui.add_button("Download HTML", hint="the cloud, instances and grasps as one page that "
                                           "opens without a server (clutt3r export-html)")
            self.tab_opener = gui.add_html("")
        self.prev.on_click(lambda ev: self.go(s, self.step - 1))
        self.next.on_click(lambda ev: self.go(s, self.step + 1))
        self.explore.on_click(lambda ev: self.leave(s))
        self.resume.on_click(lambda ev: self.go(s, self.step))
        self.download.on_click(lambda ev: send_html(s))
        # the other panels are built after this one (PANELS order): apply step 1 once they are
        threading.Thread(target=self._first_step, args=(s,), daemon=True).start()

    def _first_step(self, s: "Session") -> None:
        import time

        t0 = time.time()
        # wait for the tab to be built and for its browser to report a camera (a camera set before
        # that is overwritten by the client's initial one)
        while not s.closed and time.time() - t0 < 30 and (not s.built or s.client.camera.update_timestamp == 0.0):
            time.sleep(0.05)
        if s.closed:
            return
        self.go(s, 0)
        # A browser that just connected may still apply its initial camera after ours (seen in headless
        # chromium under load): for a few seconds, put the step's camera back when the reported one differs.
        t1 = time.time()
        while not s.closed and time.time() - t1 < 10.0 and self.step == 0 and not self.exploring:
            time.sleep(0.3)
            want = self.camera
            cam = s.client.camera
            if want is not None and (abs(cam.look_at - want.look_at).max() > 1e-3
                                     or abs(cam.position - want.position).max() > 1e-3):
                with s.lock:
                    self._set_camera(s, want)

    # -- actions -------------------------------------------------------------------------

    def leave(self, s: "Session") -> None:
        with s.lock:
            self.exploring = True
            self._buttons()
            self.text.content = f"_Exploring freely. **Resume** returns to step {self.step + 1}._"

    def go(self, s: "Session", k: int) -> None:
        """Apply step ``k`` (clamped to the tour)."""
        with s.lock:
            self.step = max(0, min(int(k), len(STEPS) - 1))
            self.exploring = False
            self.apply(s, STEPS[self.step])
            self._buttons()
            self.applied += 1

    def story_changed(self, s: "Session") -> None:
        """The demo's query stages finished (or failed): re-apply a step that was waiting for them."""
        with s.lock:
            if not self.exploring and STEPS[self.step].needs in ("query", "grasps"):
                self.go(s, self.step)

    def _buttons(self) -> None:
        self.prev.disabled = self.exploring or self.step == 0
        self.next.disabled = self.exploring or self.step == len(STEPS) - 1
        self.explore.visible = not self.exploring
        self.resume.visible = self.exploring

    # -- one step --------------------------------------------------------------------------

    def apply(self, s: "Session", step: TourStep) -> None:
        """Drive the panels to ``step`` (call with ``s.lock`` held)."""
        from clutt3r_viewer.panels import GraspsPanel, QueryPanel, ReplayPanel, UpdatesPanel

        d = s.app.data
        story = story_of(s.app)
        view = 0 if step.key == "views" else tree_view(d)
        node = tree_node(d, view) if step.key == "tree" else -1
        ev = replay_event(d)
        src = next((x for x in s.app.sources if x.name == POSE_SOURCE), None)
        facts = facts_of(d, story, view, node, ev, src.num_events if src is not None else 0)
        waiting = ""
        if step.needs and not facts.has(step.needs):
            pending = step.needs in ("query", "grasps") and story is not None and not story.complete
            failed = getattr(s.app, "tour_failed", "")
            waiting = (f"_The query could not be prepared: {failed}_" if failed else
                       "_Describing every mask for the text query (the slowest stage of the demo); this step "
                       "fills in by itself when it is ready._" if pending else
                       f"_This run has nothing for this step ({step.needs})._")

        if step.key not in ("removed", "pose") and s.scene_step() > 0:
            s.set_scene(-1)  # the steps before the grasp show the run (every tab shows the scene chosen)
        if s.state.node >= 0 or s.state.view != view:  # the view (and node) of the step
            s.select_view(view)
        if node >= 0:
            s.select_node(node)
        focus = None
        if not waiting:
            if step.key == "replay":
                p = s.panel(ReplayPanel)
                if p is not None:
                    p.set_source(s, GROUPING_SOURCE)
                    p.set_event(s, ev)
            elif step.key == "query":
                p = s.panel(QueryPanel)
                if p is not None:
                    if p.query.value != facts.query:
                        p.query.value = facts.query  # its on_update runs the query
                    elif s.state.query != facts.query or s.state.query_best < 0:
                        p.run_query(s, facts.query)
                focus = focus_points(d, s.state.query_best if s.state.query_best >= 0 else facts.target)
            elif step.key == "grasps":
                self._grasps(s, facts.target)
                focus = focus_points(d, facts.target)
            elif step.key == "removed":
                p = s.panel(UpdatesPanel)
                if p is not None:
                    p.set_update(s, 0)
            elif step.key == "pose":
                p = s.panel(ReplayPanel)
                if p is not None and src is not None:
                    p.set_source(s, POSE_SOURCE)
                    p.set_event(s, src.num_events)
                focus = self.pose_focus(d, src, facts.displaced)
                self._show_before(s, facts.displaced)
        if self.before is not None and (step.key != "pose" or waiting):
            self.before.visible = False
        g = s.panel(GraspsPanel)
        if g is not None:  # the grasps belong to their step (and to the object taken away afterwards)
            for h in (g.all, g.selected, g.region, g.contacts):
                if h is not None:
                    h.visible = step.key in ("grasps", "removed") and h is not g.all or step.key == "grasps"
        colour = step.colour
        names = [lay.name for lay in _available(s)]
        if waiting or colour not in names:
            colour = "instance"
        if step.key == "grasps" and "query" not in names:
            colour = "instance"
        s.set_color_mode(colour)
        self.camera = step_camera(d, step, view, focus)
        self._set_camera(s, self.camera)
        self.title.content = f"**{step.title}**  ({self.step + 1}/{len(STEPS)})"
        self.text.content = waiting or step.text.format(**facts.__dict__)
        if step.tab is not None:
            self.tab_opener.content = open_tab_html(step.tab, self.applied)

    def _show_before(self, s: "Session", k: int) -> None:
        """The pushed object's points where they were before the interaction, small and white: the
        replay's last step shows where they went, so both ends of the motion are in sight."""
        import numpy as np

        if k < 0:
            return
        pts = s.app.data.seg.points[s.lod_idx[s.app.data.seg.instance[s.lod_idx] == k]].astype(np.float32)
        if self.before is not None:
            self.before.remove()
        self.before = s.client.scene.add_point_cloud(
            "/tour/pose_before", pts, np.full((len(pts), 3), 255, np.uint8), point_size=s.app.point_size * 0.6,
            point_shape="circle")

    @staticmethod
    def _set_camera(s: "Session", pose) -> None:
        cam = s.client.camera
        cam.fov = pose.fov
        cam.position = pose.position  # position first, as Session._set_camera does
        cam.look_at = pose.look_at

    @staticmethod
    def pose_focus(d, src, k: int):
        """The displaced instance's points before and after its motion (the replay's last step)."""
        import numpy as np

        if src is None or k < 0:
            return None
        idx = np.flatnonzero(d.seg.instance == k)
        moved = src.points(src.num_events, idx)
        return focus_points(d, k, moved)

    def _grasps(self, s: "Session", target: int) -> None:
        """Target the query's instance in the Grasps tab, plan when the run's grasps are for another
        instance, and select the best grasp (drawn with the gripper)."""
        from clutt3r_viewer.panels import GraspsPanel

        p = s.panel(GraspsPanel)
        if p is None or target < 0:
            return
        opt = next((o for o in p.target.options if o.split()[0] == f"I{target}"), None)
        if opt is not None and p.target.value != opt:
            p.target.value = opt
        if not any(o.split(":")[1:2] and f" I{target} " in o for o in p.grasp.options[1:]):
            p.plan_for(s, target)
        if len(p.grasp.options) > 1 and p.grasp.value != p.grasp.options[1]:
            p.grasp.value = p.grasp.options[1]  # its on_update draws the gripper

    def refresh(self, s: "Session", change: Change) -> None:
        pass


def send_html(s: "Session") -> None:
    """Send this tab the run as a standalone page (``export_html``), with the labels it shows."""
    from clutt3r_viewer.export_html import scene_html

    name = (s.app.data.seg.scene_name or "clutt3r_run").replace("/", "_")
    note = s.client.add_notification("Download HTML", "writing the page ...", loading=True, with_close_button=False)
    try:
        html = scene_html(s.app.data, s.app.instance_labels())
    except Exception as e:  # noqa: BLE001  (shown; the viewer keeps running)
        note.body, note.loading, note.with_close_button = f"failed: {type(e).__name__}: {e}", False, True
        return
    s.client.send_file_download(f"{name}.html", html.encode("utf-8"), save_immediately=True)
    note.body, note.loading, note.with_close_button, note.auto_close_seconds = (
        f"{name}.html: {len(html) / 1e6:.1f} MB, opens without a server", False, True, 5.0)


class ShareHtmlPanel(Panel):
    """The Scene tab's "Download HTML" (every run, with or without a tour)."""

    tab = "Scene"
    download: "viser.GuiButtonHandle"

    def build(self, s: "Session") -> None:
        self.download = s.client.gui.add_button("Download HTML", hint="the cloud, instances and grasps as one page "
                                                "that opens without a server (clutt3r export-html)")
        self.download.on_click(lambda ev: send_html(s))


def _available(s: "Session"):
    from clutt3r_viewer.layers import available_layers

    return available_layers(s.layer_input(), s.state)
