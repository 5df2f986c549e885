"""The guided tour's story: the ordered steps and where each one points the camera (issue 16).

Pure data and numpy (no viser): ``panels/tour.py`` applies a step through the other panels'
handles. A step names the tab it opens, the colour layer, a camera target and one or two
sentences; the sentences may use the fields of ``TourFacts`` (``{query}``, ``{target}``, ...),
which come from the demo's ``DemoStory`` (``clutt3r_core.demo``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from clutt3r_viewer.camera import CameraPose, default_camera
from clutt3r_viewer.data import ViewerData

__all__ = ["TourStep", "TourFacts", "STEPS", "step_camera", "focus_points", "tree_view", "tree_node", "replay_event", "facts_of"]

CameraTarget = Literal["overview", "view", "target", "displaced"]
Needs = Literal["", "query", "grasps", "update", "pose"]


@dataclass(frozen=True)
class TourStep:
    """One step of the tour.

    Attributes:
        key: short id (tests, screenshots: ``docs/img/tour/NN_key.png``).
        title: heading shown in the tour panel.
        text: one or two sentences; ``str.format`` fields of ``TourFacts``.
        tab: the tab the step opens (None = leave the tabs as they are).
        colour: the colour layer of the step (``layers.COLOR_LAYERS`` name).
        camera: where the camera looks: the whole pile, through the step's view camera, at the
            query's target, or at the displaced object.
        needs: what the run must have for the step (``TourFacts.has``); without it the step says so.
    """

    key: str
    title: str
    text: str
    tab: str | None
    colour: str
    camera: CameraTarget
    needs: Needs = ""


STEPS: tuple[TourStep, ...] = (
    TourStep("views", "1. The views and their mask candidates",
             "The pile was seen from {n_views} posed RGB-D cameras (the frustums). Above the tabs, view {view}'s "
             "image with its noisy, overlapping mask candidates: leaves tinted by the instance they joined, parents "
             "outlined in white.", "Scene", "rgb", "view"),
    TourStep("tree", "2. One view's containment tree",
             "Each view's masks form a containment forest; its leaves are the candidate object parts. The selected "
             "mask ({node}) is highlighted in 3D and in the image.", "Tree", "instance", "view"),
    TourStep("replay", "3. Grouping the leaves across views",
             "Leaves of different views are merged greedily, spatial stage then semantic stage. This is step "
             "{event} of {n_events}: the two groups being merged are orange and blue. Press Play to watch.",
             "Replay", "replay", "overview"),
    TourStep("instances", "4. The final instances",
             "Super-voxels vote for the groups: {n_instances} instances, one colour each; their confidence and "
             "size are in the table.", "Scene", "instance", "overview"),
    TourStep("query", "5. Ask for an object by name",
             "The query '{query}' ranks every instance (class names and colour words); the best, I{target}, "
             "is highlighted. {query_note}", "Query", "query", "target", "query"),
    TourStep("grasps", "6. Grasp it",
             "{n_grasps} collision-free parallel-jaw grasps for I{target}, coloured by score; the best is drawn "
             "with the gripper.", "Grasps", "query", "target", "grasps"),
    TourStep("removed", "7. After the grasp: what changed",
             "One new image after the grasp (frame {frame}): the stored instances are matched to its masks. "
             "{removed_text}", "Updates", "update", "overview", "update"),
    TourStep("pose", "8. The neighbour's new pose",
             "{displaced_text} White: where it was. The replay is at the last of {n_pose} fitting steps "
             "(coloured by loss); drag the slider back to watch the points move.", "Replay", "replay", "displaced", "pose"),
)


@dataclass(frozen=True)
class TourFacts:
    """What the sentences name (all from the run and its ``DemoStory``; -1 / '' when unknown)."""

    n_views: int
    view: int
    node: str
    event: int
    n_events: int
    n_instances: int
    query: str
    target: int
    query_note: str
    n_grasps: int
    frame: int
    removed_text: str
    displaced_text: str
    n_pose: int
    displaced: int

    def has(self, needs: Needs) -> bool:
        return {"": True, "query": bool(self.query) and self.target >= 0, "grasps": self.target >= 0,
                "update": self.frame >= 0, "pose": self.n_pose > 0 and self.displaced >= 0}[needs]


def tree_view(data: ViewerData) -> int:
    """The view whose tree the tour shows: the one with the most non-background leaves."""
    n = data.trace.nodes
    counts = [int((n.is_leaf[data.view_nodes(v)] & ~n.background[data.view_nodes(v)]).sum())
              for v in range(len(data.trace.frames))]
    return int(np.argmax(counts)) if counts else 0


def tree_node(data: ViewerData, view: int) -> int:
    """A parent mask of ``view`` with at least two children (the tree has something to show), else
    its largest non-background leaf; -1 when the view has no mask."""
    n = data.trace.nodes
    nodes = data.view_nodes(view)
    kids = {int(i): int((n.parent[nodes] == i).sum()) for i in nodes}
    parents = [i for i in nodes if kids[int(i)] >= 2 and not n.background[i] and data.node_instance[i] >= 0]
    if parents:
        return int(max(parents, key=lambda i: kids[int(i)]))
    leaves = [int(i) for i in nodes if n.is_leaf[i] and not n.background[i]]
    return max(leaves, key=lambda i: int(data.node_points(i).sum())) if leaves else -1


def replay_event(data: ViewerData) -> int:
    """The grouping step the tour stops at: the first merge of the semantic stage when there is one
    (the step where appearance joins what geometry could not), else the middle step."""
    g = data.trace.grouping
    first = next((m.stage for m in g.merges if m.stage != "duplicate"), "")  # copies are joined before stage 1
    for n, (kind, idx) in enumerate(g.events, 1):
        if kind == "merge" and g.merges[idx].stage not in (first, "duplicate"):
            return n
    return max(1, len(g.events) // 2)


def _look(eye: np.ndarray, at: np.ndarray, fov: float) -> CameraPose:
    return CameraPose(look_at=np.asarray(at, float), position=np.asarray(eye, float), fov=float(fov))


def step_camera(data: ViewerData, step: TourStep, view: int, focus: np.ndarray | None = None) -> CameraPose:
    """The camera of ``step``: ``view`` is the step's view, ``focus`` (K, 3) world points to frame
    for the "target" and "displaced" cameras (the query's target; the pushed object before and
    after its motion), None = the whole pile."""
    base = default_camera(data)
    look = np.asarray(base.look_at, float)
    if step.camera == "view" and data.views:
        # from the side of the step's camera, turned 35 degrees about the vertical and pulled out, so its
        # frustum (with the image) stands beside the pile instead of covering it
        T = data.views[view].camera.T_world_camera
        d = T[:3, 3] - look
        a = np.radians(35.0)
        R = np.array([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0.0, 0.0, 1.0]])
        d = R @ d
        d *= np.linalg.norm(base.position - look) / max(np.linalg.norm(d), 1e-9)
        return _look(look + d, look, base.fov)
    if step.camera in ("target", "displaced") and focus is not None and len(focus):
        pts = np.asarray(focus, float)
        c = 0.5 * (np.percentile(pts, 5, axis=0) + np.percentile(pts, 95, axis=0))  # stray points do not pull it
        r = float(np.percentile(np.linalg.norm(pts - c, axis=1), 95))
        d = base.position - look
        d = d / np.linalg.norm(d)
        # the object fills about a third of the view height: its neighbours stay in sight
        dist = max(0.3, 3.0 * r / np.tan(base.fov / 2))
        return _look(c + dist * d, c, base.fov)
    return base


def focus_points(data: ViewerData, instance: int, moved: np.ndarray | None = None) -> np.ndarray | None:
    """(K, 3) the points the camera frames for ``instance``: its run points, plus ``moved`` (its
    points after a motion) when given; None for no instance."""
    if instance < 0:
        return None
    pts = data.seg.points[data.seg.instance == instance]
    if moved is not None and len(moved):
        pts = np.concatenate([pts, np.asarray(moved, pts.dtype)])
    return pts if len(pts) else None


def facts_of(data: ViewerData, story, view: int, node: int, event: int, pose_steps: int) -> TourFacts:
    """The sentences' fields from the run and its ``DemoStory`` (None: a run without a demo story)."""
    tr = data.trace
    q = story.query if story is not None else None
    target = q.target if q is not None else (story.grasp_target if story is not None else -1)
    note = ""
    if q is not None:
        if not q.correct:
            note = f"(It was meant for I{q.intended}: the query ranks I{q.target} first instead.)"
        elif story.true_removed >= 0 and q.target == story.true_removed:
            note = "It is the object the robot will take away."
    frame = story.post_frames[0] if story is not None and story.post_frames else -1
    removed = tuple(story.removed) if story is not None else ()
    displaced = tuple(story.displaced) if story is not None else ()
    removed_text = (f"I{', I'.join(map(str, removed))} {'is' if len(removed) == 1 else 'are'} gone (drawn pale where "
                    "it was last seen; the gripper stays where it grasped), the others are kept." if removed
                    else "No instance was found removed.")
    if story is not None and story.true_removed >= 0 and story.true_removed not in removed:
        removed_text += f" (The object taken away was I{story.true_removed}: the update missed it.)"
    # the camera follows the pushed object when the ground truth names it and the update re-posed it
    known = story.true_displaced if story is not None else -1
    disp = known if known in displaced else (displaced[0] if displaced else -1)
    if not displaced:
        displaced_text = "No instance was found displaced."
    elif len(displaced) == 1:
        displaced_text = (f"I{disp} was pushed: its pose is re-fitted to the new view (ICP against the new depth "
                          "when the view has depth, else the paper's chamfer, photometric and height losses).")
    else:
        displaced_text = (f"The update re-posed I{', I'.join(map(str, displaced))} (a static object can be flagged "
                          f"too, docs/update.md); the camera follows I{disp}.")
    lab = f"frame {int(tr.frames[view])}, mask {int(tr.nodes.mask_id[node])}" if node >= 0 else "none"
    return TourFacts(
        n_views=len(tr.frames), view=view, node=lab, event=event, n_events=len(tr.grouping.events),
        n_instances=data.seg.num_instances, query=q.text if q is not None else "", target=int(target),
        query_note=note, n_grasps=story.n_grasps if story is not None else 0, frame=frame,
        removed_text=removed_text, displaced_text=displaced_text, n_pose=pose_steps, displaced=disp)
