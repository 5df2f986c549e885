"""Evidence for the instances an update added (status "new"), so a query after the update ranks them.

An added instance has no masks in the run's initial views; it was found as a mask candidate in
the post-interaction view (``update.json`` "new_masks"). The backend describes that mask crop
in that view and it is aggregated as a run instance's masks are (``aggregate_instances``, one
mask). Shared by ``RunQuery`` (``clutt3r query`` / ``clutt3r grasp`` after an update) and the
viewer's Query tab.
"""

from __future__ import annotations

from types import SimpleNamespace
from typing import Iterable

import numpy as np

from clutt3r_core.query.evidence import InstanceEvidence, NodeEvidence, aggregate_instances

__all__ = ["added_instance_evidence"]


def added_instance_evidence(base: InstanceEvidence, node_evidence: NodeEvidence, grounder, scene,
                            adds: Iterable[tuple[int, int, int]]) -> tuple[InstanceEvidence, frozenset[int]]:
    """``base`` (the run's instance evidence, rows = ids) extended to every id of ``adds``
    ((instance id, frame, mask id in that frame's view of ``scene``)), each row described by
    ``grounder`` from its mask; rows of ids that could not be described (the frame or its mask
    is not in the scene folder, mask id < 0) stay zeros. Returns (evidence, the ids described)."""
    from clutt3r_core.language.colors import color_shares

    adds = [(int(k), int(f), int(m)) for k, f, m in adds if int(m) >= 0]
    if not adds or scene is None:
        return base, frozenset()
    n = max(base.num_instances, 1 + max(k for k, _, _ in adds))
    src = (base.grounding, base.colors, base.features)
    out = [np.zeros((n, x.shape[1]), np.float32) for x in src]
    for x, y in zip(out, src):
        x[: base.num_instances] = y
    n_views = np.zeros(n, np.int32)
    n_views[: base.num_instances] = base.n_views
    done = set()
    for frame in sorted({f for _, f, _ in adds}):
        these = [(k, m) for k, f, m in adds if f == frame]
        try:
            v = scene.view_by_frame(frame)
            masks = v.masks.stack([v.masks.index_of(m) for _, m in these])
        except (KeyError, ValueError, AttributeError):
            continue  # the frame or its masks are not in the scene folder: left undescribed
        g = grounder.mask_evidence(v.rgb, masks)
        m = len(these)
        ev = NodeEvidence(np.arange(m), g.features, g.grounding, color_shares(v.rgb, masks),
                          masks.reshape(m, -1).sum(axis=1).astype(np.float32),
                          np.full(m, masks.shape[1] * masks.shape[2], np.float32), node_evidence.backend,
                          node_evidence.version, node_evidence.label_embeddings, node_evidence.labels)
        agg = aggregate_instances(SimpleNamespace(num_instances=m, instance_nodes=lambda i: (i,)), ev,
                                  label_mode=node_evidence.label_embeddings is not None)
        for j, (k, _) in enumerate(these):
            for x, y in zip(out, (agg.grounding, agg.colors, agg.features)):
                x[k] = y[j]
            n_views[k] = 1
            done.add(k)
    return InstanceEvidence(out[0], out[1], out[2], n_views), frozenset(done)
