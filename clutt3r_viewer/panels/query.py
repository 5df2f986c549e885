"""The Query tab: rank instances by a text query, colour them by score, and say why the best won.

Two sources of scores:

* the language backend (``clutt3r_core.query``, default text embedder of the registry, e.g.
  ``imagenet-minilm``): the run's masks are described once (a few seconds per view, shown in
  the tab), then each phrase is scored by class names and colour words; the tab lists the
  ranking with each instance's reason (class name and its probability, colour shares) and
  whether the answer is confident;
* a text embedder that shares the space of the run's own mask embeddings
  (``app.text_embedder``, e.g. a CLIP run): cosine scores, as before.

Both set ``state.query_scores`` (the ``query`` colour layer: a heat map over instances) and
``state.query_best`` (highlighted; the Grasps tab can take it as its target).

Before any update the instances ranked are the Edit tab's as they are now
(``scene_step.step_zero_of``, the core's ``update.run_labels.step_zero_labels``): deleted and merged
ids are not ranked, a merged instance is ranked once with its parts' evidence mixed by size
(``query.corrected_evidence``), as ``clutt3r query`` ranks the run's correction log; an edit
ranks the last query again.
"""

from __future__ import annotations

import threading
from types import SimpleNamespace
from typing import TYPE_CHECKING

import numpy as np

from clutt3r_viewer.panels.base import Change, Panel

if TYPE_CHECKING:
    import viser

    from clutt3r_viewer.app import Session, ViewerApp

__all__ = ["QueryPanel", "language_backend_name"]

_RQ_LOCK = threading.Lock()


def language_backend_name() -> str | None:
    """The registry's default text embedder when it can be built without arguments (a
    backend that needs weight paths, like clip-onnx, cannot), else None."""
    try:
        from clutt3r_core.registry import REGISTRY, default_backend

        name = default_backend("text_embedder")
        if name is None or name in ("open-clip", "clip-onnx"):
            return None
        REGISTRY.get("text_embedder", name)
        return name
    except Exception:  # a broken registry must not break the viewer
        return None


def _in_scene(s: "Session", scores: np.ndarray, text_embedding: np.ndarray | None,
              scored: frozenset[int] = frozenset()) -> tuple[np.ndarray, list[str]]:
    """Per-instance ``scores`` (rows = instance ids) for the scene the tab shows (after its
    updates): one score per instance id of the chain, NaN = not ranked (not in that scene:
    removed by then or added later; added but not described), and the lines that say so. An added
    instance keeps its row of ``scores`` when it is in ``scored`` (the language backend described
    its mask), else it is scored by its mask's embedding (``NewInstance.embedding``, the state's
    embedder) when a text embedding in that space is given (the run's own text embedder)."""
    step = s.scene_step()
    if step == 0:
        return scores, []
    sc = s.scene()
    n = max(len(scores), int(sc.present.max(initial=-1)) + 1)
    out = np.full(n, np.nan, np.float32)
    out[: len(scores)] = scores
    out[~np.isin(np.arange(n), sc.present)] = np.nan
    gone = [k for k in sc.removed if k < n]
    emb = {a.instance: a.embedding for u in s.app.data.updates[:step] if u.result is not None for a in u.result.added}
    unscored = []
    for k in sorted(sc.added_in):
        e = emb.get(k)
        if k in scored and k < len(scores):
            continue
        if text_embedding is not None and e is not None and e.shape == np.shape(text_embedding) and np.any(e):
            t = np.asarray(text_embedding, np.float32)
            out[k] = float(e @ t / max(float(np.linalg.norm(t)), 1e-12))
        else:
            out[k] = np.nan
            unscored.append(k)
    removed = f"; removed, not ranked: {', '.join(f'I{k}' for k in gone)}" if gone else ""
    note = [f"\n_scene after update {step}_" + removed
            + (f"; added {', '.join(f'I{k}' for k in sorted(sc.added_in))}" if sc.added_in else "")]
    if unscored:
        note.append(f"_not ranked: {', '.join(f'I{k}' for k in unscored)} (added by an update; its mask in the "
                    "post view could not be described: no scene folder, or no mask id)_")
    return out, note


def _carried_scores(s: "Session", scores: np.ndarray) -> np.ndarray:
    """Per-run-instance ``scores`` (the run's own embedder's cosines) on the ids of the scene shown:
    at step 0 the Edit tab's now (``scene_step.step_zero_of``), after updates the labelling the
    chain was computed from (``chain_inputs_of``); each id mixes its run instances' scores by its
    points' share (``update.run_labels.run_share``, as the language path mixes the evidence), NaN for
    ids that are deleted, merged or have no fused point. The run's own ids: ``scores`` as they are."""
    data = s.app.data
    if s.scene_step() == 0:
        from clutt3r_viewer.scene_step import step_zero_of

        z = step_zero_of(data, getattr(s.app, "annotations", None))
        if not z.corrected:
            return scores
        share, ids = z.share, z.labels.ids
    else:
        share, ids = _chain_share(data)
        if share is None:
            return scores
    out = np.full(share.shape[0], np.nan, np.float32)
    rows = share[ids]
    out[ids] = (rows @ np.asarray(scores, np.float64)).astype(np.float32)
    out[ids[rows.sum(axis=1) == 0]] = np.nan  # rim points only: no evidence
    return out


def _chain_share(data) -> tuple[np.ndarray | None, np.ndarray | None]:
    """(``update.run_labels.run_share`` of the labelling the update chain of ``data`` was computed
    from, the chain's ids) (``scene_step.chain_inputs_of``), (None, None) when its ids are the run's.
    Once per chain here, not in ``chain_inputs_of`` (``ChainInputs.run_share``): 36 ms at 1M points a
    step's scene would pay for a value the other tabs do not read."""
    hit = data._cache.get("chain_share")
    if hit is None:
        from clutt3r_core.update.run_labels import run_share
        from clutt3r_viewer.scene_step import chain_inputs_of

        chain = chain_inputs_of(data, len(data.updates))  # the chain's labelling and ids, as the scenes shown
        same = np.array_equal(chain.instance, data.seg.instance)
        hit = data._cache["chain_share"] = (None, None) if same else (
            run_share(chain.instance, data.seg, chain.num_ids), chain.ids)
    return hit


def added_instance_evidence(rq, data) -> tuple[object, frozenset[int]]:
    """``rq.instances`` (the run's ``InstanceEvidence``) on the ids of the update chain of ``data``,
    as ``clutt3r query --step`` carries it: rows mixed by point share when the chain was computed
    from a corrected labelling (``scene_step.chain_inputs_of``; the core's
    ``query.corrected_evidence`` over ``update.run_labels.run_share``), then one row per
    instance id the updates added, each described by the backend from its mask in the post view
    that added it (``query.added.added_instance_evidence``); rows of ids without a description are
    zeros. Returns (evidence, the added ids described)."""
    from clutt3r_core.io import load_scene
    from clutt3r_core.query import corrected_evidence
    from clutt3r_core.query.added import added_instance_evidence as describe

    base = rq.instances
    share = _chain_share(data)[0]
    if share is not None:
        base = corrected_evidence(base, share, rq.evidence.label_embeddings is not None)
    adds = [(a.instance, u.frame, a.mask_id) for u in data.updates if u.result is not None
            for a in u.result.added if a.mask_id >= 0]
    if not adds or data.scene_root is None:
        return base, frozenset()
    return describe(base, rq.evidence, rq.grounder, load_scene(data.scene_root), adds)


class QueryPanel(Panel):
    tab = "Query"
    query: "viser.GuiTextHandle"
    find: "viser.GuiButtonHandle"
    result: "viser.GuiMarkdownHandle"

    @classmethod
    def available(cls, app: "ViewerApp") -> bool:
        return app.text_embedder is not None or language_backend_name() is not None

    def build(self, s: "Session") -> None:
        gui = s.client.gui
        self.query = gui.add_text("Query", "")
        self.find = gui.add_button("Find")
        self.find.on_click(lambda ev: self.run_query(s, self.query.value))
        self.query.on_update(lambda ev: self.run_query(s, self.query.value))
        name = s.app.text_embedder.name if s.app.text_embedder is not None else language_backend_name()
        self.result = gui.add_markdown(f"_text embedder: `{name}`_")

    def refresh(self, s: "Session", change: Change) -> None:
        # another scene shown (an update chosen), or an edit while the run itself is shown (the ids at
        # step 0; a scene after updates has the chain's ids, which no edit changes): rank the instances
        # of that scene again, off the session's lock (run_query takes it and broadcasts its own change)
        if s.state.query and (change & Change.SCENE or change & Change.LABELS and s.scene_step() == 0):
            threading.Thread(target=self.run_query, args=(s, s.state.query, False), daemon=True).start()

    # -- the language backend -----------------------------------------------------------------

    def _run_query_object(self, s: "Session"):
        """The app's ``RunQuery`` (built once per app: the masks are embedded on first use)."""
        with _RQ_LOCK:
            rq = getattr(s.app, "_run_query", None)
            if rq is not None and rq.seg is s.app.data.seg:
                return rq
            from clutt3r_core.query import RunQuery, create_grounder

            data = s.app.data
            if not data.views or any(v.masks is None for v in data.views):
                raise RuntimeError("the run was opened without its scene images (--scene): masks cannot be described")
            self.result.content = f"_describing {len(data.views)} views' masks with `{language_backend_name()}` ..._"
            scene = SimpleNamespace(initial_views=data.views, name=data.seg.scene_name)
            rq = RunQuery.from_scene(data.seg, scene, create_grounder(language_backend_name()))
            s.app._run_query = rq
            return rq

    def _added_query_object(self, s: "Session", rq):
        """``rq`` on the ids of the update chain, the instances the updates added described too
        (``added_instance_evidence``, once per app), and the added ids described."""
        with _RQ_LOCK:
            hit = getattr(s.app, "_run_query_added", None)
            if hit is not None and hit[0] is rq:
                return hit[1], hit[2]
            from dataclasses import replace

            ev, done = added_instance_evidence(rq, s.app.data)
            out = (rq, replace(rq, instances=ev), done)
            s.app._run_query_added = out
            return out[1], out[2]

    def _step_zero_query_object(self, s: "Session", rq):
        """``rq`` on the Edit tab's labelling now (``RunQuery.with_labelling`` of
        ``scene_step.step_zero_of``), kept for one labelling (an edit makes a new one)."""
        from clutt3r_viewer.scene_step import step_zero_of

        z = step_zero_of(s.app.data, getattr(s.app, "annotations", None))
        with _RQ_LOCK:
            hit = getattr(s.app, "_run_query_step0", None)
            if hit is not None and hit[0] is rq and hit[1] is z:
                return hit[2]
            out = rq.with_labelling(z)
            s.app._run_query_step0 = (rq, z, out)
            return out

    def _language_scores(self, s: "Session", text: str):
        rq = self._run_query_object(s)
        scored: frozenset[int] = frozenset()
        step = s.scene_step()
        if step > 0:  # only the instances of the scene shown, scored as `clutt3r query --step` scores them
            rq, scored = self._added_query_object(s, rq)
            sc = s.scene()
            ids = [k for k in sc.present.tolist() if k not in sc.added_in or k in scored]
            res = rq.query_among(text, ids, step, f"scene after update {step}", int(sc.present.max(initial=-1)) + 1)
        else:  # the Edit tab's ids now (rq itself when the edits change no label)
            res = self._step_zero_query_object(s, rq).query(text)
        scores, note = _in_scene(s, res.scores.astype(np.float32), None, scored)
        lines = [f"**{text}** → I{res.target} "
                 + ("(confident)" if res.confident else "(_not confident: nothing matches clearly_)"),
                 "", "| inst | score | why |", "|---|---|---|"]
        for k in res.ranking[:8]:
            why = res.explanations[k].summary().replace("|", "/")
            lines.append(f"| I{k} | {res.scores[k]:+.2f} | {why} |")
        lines.append(f"\n_{res.backend}, {res.time_s * 1e3:.0f} ms_")
        return scores, res.target, "\n".join(lines + note)

    # -- shared-space text embedder (the run's own) --------------------------------------------

    def _cosine_scores(self, s: "Session", text: str):
        emb = s.app.text_embedder.embed_text([text])[0]
        scores = _carried_scores(s, s.app.data.instance_text_scores(emb))
        scores, note = _in_scene(s, scores, emb)
        ranked = np.flatnonzero(np.isfinite(scores))
        if len(ranked) == 0:
            return scores, None, "_no instances_"
        order = ranked[np.argsort(-scores[ranked], kind="stable")]
        content = "\n".join([f"**{text}** → I{int(order[0])}", "", "| inst | score |", "|---|---|"]
                            + [f"| I{int(k)} | {scores[k]:.3f} |" for k in order[:8]] + note)
        return scores, int(order[0]), content

    def run_query(self, s: "Session", text: str, show: bool = True) -> None:
        """Score every instance of the scene shown against ``text``; the best one is highlighted
        (``query`` colour layer, switched to when ``show``)."""
        text = text.strip()
        scores = best = None
        content = "_empty query_"
        if text:
            try:
                if s.app.text_embedder is not None:
                    scores, best, content = self._cosine_scores(s, text)
                else:
                    scores, best, content = self._language_scores(s, text)
            except Exception as e:  # shown in the tab; the viewer keeps running
                scores, best, content = None, None, f"_query failed: {type(e).__name__}: {e}_"
        with s.lock:
            st = s.state
            st.query = text
            if scores is None or best is None or len(scores) == 0 or not np.isfinite(scores).any():
                st.query_best, st.query_scores = -1, None
                if st.color_mode == "query":
                    st.color_mode = "instance"
            else:
                st.query_best, st.query_scores = int(best), np.asarray(scores, np.float32)
                if show:
                    st.color_mode = "query"
            self.result.content = content
            s.changed(Change.COLOUR)
