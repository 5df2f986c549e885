"""The demo's story, computed once and cached in the run folder (issue 16).

``build_demo(out, DemoConfig())`` makes everything the viewer's guided tour shows, in stages:

1. ``scene``: a generated pre/post pair (``synth``, ``prepost=True``: one object taken away, a
   neighbour pushed) written to ``OUT/scene``, or a scene folder given by the user (a real
   sample; its post-interaction frames are those without depth or listed as post frames);
2. ``segment``: the pre views segmented, the run saved to ``OUT``;
3. ``query evidence``: every mask described by the language backend, cached in
   ``OUT/query_cache.npz`` (``clutt3r_core.query``);
4. ``update``: each post-interaction frame, chained (``clutt3r_core.update``), saved under
   ``OUT/updates/`` as ``clutt3r update`` does;
5. ``suggested query``: a phrase that names the removed object *and that the query ranks
   first* (measured here, not assumed: see ``choose_query``);
6. ``grasps``: the target's grasps (``OUT/grasps.json`` / ``grasps.npz``).

The outcome is a ``DemoStory`` saved as ``OUT/demo.json``; a second ``build_demo`` with the same
configuration reads it back and recomputes nothing. Never imports the viewer.
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from clutt3r_core.errors import Clutt3rError, SceneError, SceneFileError

__all__ = ["DemoConfig", "StageTime", "QueryChoice", "DemoStory", "build_demo", "complete_demo", "load_story", "choose_query",
           "instance_objects", "DEMO_JSON"]

DEMO_JSON = "demo.json"
_VERSION = 1


@dataclass(frozen=True)
class DemoConfig:
    """What the demo builds.

    Attributes:
        scene: a scene folder to use instead of a generated one (None = generate).
        seed: random seed of the generated scene.
        preset: clutter of the generated scene (easy / intermediate / hard).
        views: initial views of the generated scene (ours: 8 as the paper, Sec. IV-A).
        width: image width of the generated views, pixels.
        height: image height, pixels.
        focal_px: focal length of the generated cameras at 640 px width (the generator's default).
        top_grasps: grasps kept for the target (the Grasps tab draws them all).
        backend: text embedder of the query (None = the registry's default).
        max_post_frames: post-interaction frames applied, in order (ours: 2, sample_seq1 has 8 and 9).
    """

    scene: Path | None = None
    seed: int = 0
    preset: str = "intermediate"
    views: int = 8
    width: int = 640
    height: int = 480
    focal_px: float = 400.0
    top_grasps: int = 10
    backend: str | None = None
    max_post_frames: int = 2

    def __post_init__(self) -> None:
        if self.views < 1 or self.width < 16 or self.height < 16:
            raise SceneError(f"DemoConfig: views >= 1 and images >= 16 px, got {self.views} views "
                             f"{self.width}x{self.height}")
        if self.top_grasps < 1 or self.max_post_frames < 0:
            raise SceneError("DemoConfig: top_grasps >= 1 and max_post_frames >= 0")

    def key(self) -> dict:
        d = asdict(self)
        d["scene"] = None if self.scene is None else str(Path(self.scene).resolve())
        return {"version": _VERSION, **d}


@dataclass(frozen=True)
class StageTime:
    """Time of one demo stage: ``seconds`` wall, ``cpu_seconds`` CPU of this process (all its
    threads; on a shared machine the wall time also counts waiting for the cores);
    ``cached``: read back from a previous build."""

    stage: str
    seconds: float
    cpu_seconds: float = 0.0
    cached: bool = False


@dataclass(frozen=True)
class QueryChoice:
    """The suggested query and how it was checked.

    Attributes:
        text: the phrase ("the red mug").
        target: the instance the query ranks first.
        intended: the instance the phrase was made for (the removed object when known).
        correct: target == intended (only phrases with correct=True are chosen when one exists).
        confident: the query's own confidence flag.
        tried: every (phrase, instance it ranked first) tried, in order.
        how: one sentence: where the phrase came from (ground truth name or the backend's labels).
    """

    text: str
    target: int
    intended: int
    correct: bool
    confident: bool
    tried: tuple[tuple[str, int], ...]
    how: str


@dataclass(frozen=True)
class DemoStory:
    """What the tour shows (saved as ``OUT/demo.json``).

    Attributes:
        run: the run folder.
        scene: the scene folder.
        generated: True for a generated scene (ground truth known).
        query: the suggested query, or None without a language backend (the reason in ``notes``).
        grasp_target: the instance grasped (the query's target), -1 when none.
        n_grasps: grasps saved for it.
        post_frames: the post-interaction frames applied, in order.
        removed: instances the first update reported removed.
        displaced: instances the first update re-posed (pose replay).
        true_removed: the instance of the object the generator took away (-1 unknown).
        true_displaced: the instance of the object it pushed (-1 unknown).
        stages: wall time per stage of the build that made the run.
        notes: what is missing or not as intended, one sentence each.
        complete: False until the query stages ran (``build_demo(with_query=False)``).
    """

    run: Path
    scene: Path
    generated: bool
    query: QueryChoice | None
    grasp_target: int
    n_grasps: int
    post_frames: tuple[int, ...]
    removed: tuple[int, ...]
    displaced: tuple[int, ...]
    true_removed: int
    true_displaced: int
    stages: tuple[StageTime, ...]
    notes: tuple[str, ...] = ()
    complete: bool = True

    def to_json(self) -> dict:
        d = asdict(self)
        d["run"], d["scene"] = str(self.run), str(self.scene)
        return d

    @staticmethod
    def from_json(d: dict) -> "DemoStory":
        q = d.get("query")
        qc = None if q is None else QueryChoice(q["text"], int(q["target"]), int(q["intended"]), bool(q["correct"]),
                                                bool(q["confident"]), tuple((str(a), int(b)) for a, b in q["tried"]),
                                                q["how"])
        return DemoStory(Path(d["run"]), Path(d["scene"]), bool(d["generated"]), qc, int(d["grasp_target"]),
                         int(d["n_grasps"]), tuple(d["post_frames"]), tuple(d["removed"]), tuple(d["displaced"]),
                         int(d["true_removed"]), int(d["true_displaced"]),
                         tuple(StageTime(s["stage"], float(s["seconds"]), float(s.get("cpu_seconds", 0.0)), True)
                               for s in d["stages"]),
                         tuple(d.get("notes", ())), bool(d.get("complete", True)))


def load_story(run: str | Path) -> DemoStory | None:
    """The story of a demo run (``OUT/demo.json``), or None when the run is not a demo run."""
    p = Path(run) / DEMO_JSON
    if not p.is_file():
        return None
    try:
        return DemoStory.from_json(json.loads(p.read_text())["story"])
    except (OSError, KeyError, TypeError, ValueError, json.JSONDecodeError) as e:
        raise SceneFileError(p, f"unreadable demo story ({e}); delete it to rebuild the demo") from None


# ------------------------------------------------------------------ pieces


def instance_objects(seg, gt_points: np.ndarray, gt_labels: np.ndarray, radius: float = 0.005) -> np.ndarray:
    """(I,) int32 ground-truth object of each instance: the majority label of its points' nearest
    ground-truth points within ``radius`` metres (-1 when none of its points has one)."""
    from scipy.spatial import cKDTree

    out = np.full(seg.num_instances, -1, np.int32)
    if len(gt_points) == 0:
        return out
    d, j = cKDTree(np.asarray(gt_points, np.float64)).query(seg.points, distance_upper_bound=radius)
    lab = np.where(np.isfinite(d), np.asarray(gt_labels)[np.minimum(j, len(gt_labels) - 1)], -1)
    for k in range(seg.num_instances):
        v = lab[(seg.instance == k) & (lab >= 0)]
        if len(v):
            out[k] = int(np.bincount(v).argmax())
    return out


def choose_query(rq, candidates: list[tuple[int, list[str], str]]) -> QueryChoice | None:
    """The first phrase that the query ranks on its intended instance.

    ``candidates``: (intended instance, phrases to try in order, where they come from), in
    order of preference. Confident correct answers win over unconfident correct ones; when no
    phrase is ranked correctly the first phrase tried is returned with ``correct=False`` (the
    tour then says so). None when there is nothing to try.
    """
    tried: list[tuple[str, int]] = []
    first = None
    best_unconfident = None
    for k, phrases, how in candidates:
        for p in phrases:
            res = rq.query(p)
            t = -1 if res.target is None else int(res.target)
            tried.append((p, t))
            if first is None:
                first = (p, t, k, bool(res.confident), how)
            if t == k:
                if res.confident:
                    return QueryChoice(p, t, k, True, True, tuple(tried), how)
                if best_unconfident is None:
                    best_unconfident = (p, t, k, False, how)
    pick = best_unconfident or first
    if pick is None:
        return None
    p, t, k, conf, how = pick
    return QueryChoice(p, t, k, t == k, conf, tuple(tried), how)


def _instance_of(seg, objs: np.ndarray, obj: int) -> int:
    """The largest instance whose ground-truth object is ``obj`` (-1 when none)."""
    ks = np.flatnonzero(objs == obj)
    if len(ks) == 0:
        return -1
    return int(ks[int(np.argmax([int((seg.instance == k).sum()) for k in ks]))])


def _generated_candidates(scene, seg, removed_instance: int) -> list:
    """Phrases from the ground-truth names: the removed object's first, then the others'."""
    from clutt3r_core.language.colors import color_name_of

    gt = scene.ground_truth
    objs = instance_objects(seg, gt.points, gt.point_labels)
    cands = []
    for o in gt.objects:
        k = _instance_of(seg, objs, o.id)
        if k < 0:
            continue
        names = [o.category] + ([f"{color_name_of(o.color)} {o.category}"] if o.color is not None else [])
        how = ("the ground-truth name of the object the generator takes away" if k == removed_instance
               else "the ground-truth name of another object (no phrase for the removed one was ranked on it)")
        cands.append((k, names, how))
    cands.sort(key=lambda c: c[0] != removed_instance)  # the removed object's phrases first
    return cands


def _label_candidates(rq, order: list[int], top: int = 3) -> list:
    """Phrases from the backend's own best labels for each instance (scenes without ground truth)."""
    ev, inst = rq.evidence, rq.instances
    if not ev.labels:
        return []
    cands = []
    for k in order:
        best = np.argsort(-inst.grounding[k])[:top]
        cands.append((k, [ev.labels[int(i)] for i in best],
                      "the language backend's own best class names for the removed instance" if k == order[0]
                      else "the backend's best class names for another instance"))
    return cands


# ------------------------------------------------------------------ the build


def build_demo(out: str | Path, config: DemoConfig = DemoConfig(), with_query: bool = True,
               log: Callable[[str], None] = lambda s: print(s, flush=True)) -> DemoStory:
    """Build (or read back) the demo run in ``out`` (module docstring).

    ``with_query=False`` stops after the update (stages 1, 2, 4): the viewer can show the first
    steps of the tour while ``complete_demo`` describes the masks (the slowest stage) in the
    background. A second call reads ``demo.json`` and only runs what is still missing.
    """
    out = Path(out)
    story = _cached(out, config)
    if story is not None:
        log(f"{out}: demo run already built (demo.json; delete it to rebuild)")
        if with_query and not story.complete:
            story = complete_demo(out, config, story, log=log)
        return story
    stages: list[StageTime] = []
    notes: list[str] = []

    cpu = [time.process_time()]

    def stage(name: str, t0: float) -> None:
        stages.append(StageTime(name, time.perf_counter() - t0, time.process_time() - cpu[0]))
        cpu[0] = time.process_time()
        log(f"  {name}: {stages[-1].seconds:.1f} s ({stages[-1].cpu_seconds:.1f} s CPU)")

    from clutt3r_core.io import load_scene
    from clutt3r_core.pipeline import segment
    from clutt3r_core.runs import save_run

    t = time.perf_counter()
    if config.scene is None:
        from clutt3r_core.synth import SynthConfig, generate, write_synth_scene

        log(f"generating a '{config.preset}' pre/post scene (seed {config.seed}, {config.views} views) ...")
        res = generate(SynthConfig(seed=config.seed, preset=config.preset, views=config.views, width=config.width,
                                   height=config.height, focal_px=config.focal_px, prepost=True), progress=False)
        scene_dir = write_synth_scene(res.scene, out / "scene", info=res.info, contact_sheet=False)
        scene = res.scene
    else:
        scene_dir = Path(config.scene)
        log(f"loading {scene_dir} ...")
        scene = load_scene(scene_dir)
    stage("scene", t)

    t = time.perf_counter()
    log("segmenting the pre-interaction views ...")
    seg = segment(scene)
    save_run(seg, out, scene_root=scene_dir)
    stage("segment", t)
    log(f"  {seg.num_instances} instances, {len(seg.points):,} points")

    t = time.perf_counter()
    post = [v for v in scene.post_views if v.masks is not None][: config.max_post_frames]
    skipped = [v.frame for v in scene.post_views if v.masks is None]
    if skipped:
        notes.append(f"post-interaction frames {skipped} have no mask candidates: not applied")
    removed: tuple[int, ...] = ()
    displaced: tuple[int, ...] = ()
    if post:
        log(f"updating from post-interaction frame(s) {[v.frame for v in post]} ...")
        removed, displaced = _updates(out, post)
    else:
        notes.append("the scene has no post-interaction frame with masks: no update to show")
    stage("update", t)

    true_removed = true_displaced = -1
    if config.scene is None and scene.ground_truth is not None:
        it = res.info.interaction
        objs = instance_objects(seg, scene.ground_truth.points, scene.ground_truth.point_labels)
        true_removed, true_displaced = _instance_of(seg, objs, it.removed_object), _instance_of(seg, objs, it.displaced_object)
        if true_removed >= 0 and true_removed not in removed:
            notes.append(f"the update did not report I{true_removed} (the object taken away) as removed")
        if true_displaced >= 0 and true_displaced not in displaced:
            notes.append(f"the update did not re-pose I{true_displaced} (the object pushed)")
    story = DemoStory(out, scene_dir, config.scene is None, None, -1, 0, tuple(v.frame for v in post), removed,
                      displaced, true_removed, true_displaced, tuple(stages), tuple(notes), complete=False)
    _save(out, config, story)
    if with_query:
        story = complete_demo(out, config, story, log=log)
    return story


def complete_demo(out: str | Path, config: DemoConfig, story: DemoStory,
                  log: Callable[[str], None] = lambda s: print(s, flush=True)) -> DemoStory:
    """Stages 3, 5 and 6 (query evidence, suggested query, grasps) on a run ``build_demo`` made
    with ``with_query=False``; saves and returns the complete story."""
    from dataclasses import replace

    from clutt3r_core.io import load_scene
    from clutt3r_core.runs import load_run

    out = Path(out)
    stages = list(story.stages)
    notes = list(story.notes)

    cpu = [time.process_time()]

    def stage(name: str, t0: float) -> None:
        stages.append(StageTime(name, time.perf_counter() - t0, time.process_time() - cpu[0]))
        cpu[0] = time.process_time()
        log(f"  {name}: {stages[-1].seconds:.1f} s ({stages[-1].cpu_seconds:.1f} s CPU)")

    seg = load_run(out)
    # the object taken away: the ground truth's when generated, else the first the update reported removed
    known = story.true_removed if story.true_removed >= 0 else (story.removed[0] if story.removed else -1)
    rq = None
    t = time.perf_counter()
    try:
        from clutt3r_core.query import RunQuery

        log("describing the masks for text queries ...")
        # the story queries the scene as segmented: the object it names is the one the update then removes
        rq = RunQuery.open(out, backend=config.backend, scene=story.scene, step=0)
    except (Clutt3rError, ImportError) as e:
        notes.append(f"no text query: {e}")
    stage("query evidence", t)

    t = time.perf_counter()
    choice = None
    scene = None
    if rq is not None and seg.num_instances:
        if story.generated:
            scene = load_scene(story.scene)
            cands = _generated_candidates(scene, seg, story.true_removed)
        else:
            sizes = np.bincount(seg.instance[seg.instance >= 0], minlength=seg.num_instances)
            rest = [int(k) for k in np.argsort(-sizes) if int(k) not in story.removed]
            cands = _label_candidates(rq, list(story.removed) + rest)
        choice = choose_query(rq, cands)
        if choice is not None:
            log(f"  suggested query: '{choice.text}' -> I{choice.target}"
                + ("" if choice.correct else f" (made for I{choice.intended}: not ranked first)"))
            if not choice.correct:
                notes.append(f"no phrase tried was ranked on its object; the tour shows '{choice.text}' anyway")
            if known >= 0 and choice.target != known:
                notes.append(f"the suggested query names I{choice.target}, not the removed I{known}: no phrase tried "
                             "was ranked first on the removed object")
    stage("suggested query", t)

    t = time.perf_counter()
    target = choice.target if choice is not None else known
    n_grasps = 0
    if target >= 0:
        from clutt3r_core.grasping.request import depth_views, request_from_segmentation
        from clutt3r_core.registry import create_backend

        if scene is None:
            scene = load_scene(story.scene)
        log(f"planning grasps for I{target} ...")
        gs = create_backend("grasp_planner").plan(request_from_segmentation(seg, target, depth_views(scene)))
        gs = gs.top(config.top_grasps)
        gs.save_json(out / "grasps.json", target, choice.text if choice is not None else None)
        gs.save_npz(out / "grasps.npz")
        n_grasps = len(gs)
        if n_grasps == 0:
            notes.append(f"no collision-free grasp for I{target}" + (f": {gs.message}" if gs.message else ""))
    stage("grasps", t)
    story = replace(story, query=choice, grasp_target=target, n_grasps=n_grasps, stages=tuple(stages),
                    notes=tuple(notes), complete=True)
    _save(out, config, story)
    log(f"demo built in {sum(s.seconds for s in stages if not s.cached):.1f} s: "
        + ", ".join(f"{s.stage} {s.seconds:.1f} s" for s in stages if not s.cached))
    return story


def _save(out: Path, config: DemoConfig, story: DemoStory) -> None:
    from clutt3r_core.io.images import atomic_write_bytes

    atomic_write_bytes(out / DEMO_JSON, json.dumps({"key": config.key(), "story": story.to_json()}, indent=1).encode())


def _updates(out: Path, post) -> tuple[tuple[int, ...], tuple[int, ...]]:
    """Apply the post frames in order (a chain, as ``clutt3r update`` does); the first update's
    removed and displaced instances."""
    import shutil

    from clutt3r_core.io.images import write_png
    from clutt3r_core.update.overlay import update_overlay
    from clutt3r_core.update.state import apply_update, save_state, state_from_run
    from clutt3r_core.update.update import update_scene

    shutil.rmtree(out / "updates", ignore_errors=True)  # a rebuilt run: its old chain is stale
    state = state_from_run(out)
    parent = out
    first = None
    for v in post:
        res = update_scene(state, v)
        new = apply_update(state, res)
        folder = out / "updates" / f"{new.step:02d}_frame_{v.frame:06d}"
        save_state(new, folder, res, parent=parent)
        write_png(folder / "overlay.png", update_overlay(state, v, res))
        first = first or res
        state, parent = new, folder
    assert first is not None
    return first.by_status("removed"), first.by_status("displaced")


def _cached(out: Path, config: DemoConfig) -> DemoStory | None:
    from clutt3r_core.runs import is_run_folder

    p = out / DEMO_JSON
    if not p.is_file() or not is_run_folder(out):
        return None
    try:
        doc = json.loads(p.read_text())
    except (OSError, json.JSONDecodeError):
        return None
    if doc.get("key") != config.key() or not (out / "updates").is_dir() and "post_frames" in doc.get("story", {}) \
            and doc["story"]["post_frames"]:
        return None
    return DemoStory.from_json(doc["story"])
