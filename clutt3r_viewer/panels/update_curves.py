"""Loss and IoU curves of the selected update's pose optimisations (Updates tab, issue 10).

Follows the Updates tab's frame slider (``state.update``): one line per optimised instance,
total loss and IoU over the iterations (``update_sources.update_curves``). The iterations
themselves are stepped in 3D by the Replay tab's "scene updates: pose iterations" source.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from clutt3r_viewer.panels.base import Change, Panel
from clutt3r_viewer.panels.update_sources import update_curves
from clutt3r_viewer.data import PALETTE

if TYPE_CHECKING:
    import viser

    from clutt3r_viewer.app import Session, ViewerApp

__all__ = ["UpdateCurvesPanel"]


def _series(ids: tuple[int, ...], what: str):
    from viser import uplot

    col = lambda k: "#%02x%02x%02x" % tuple(int(c) for c in PALETTE[k % len(PALETTE)])  # noqa: E731
    return (uplot.Series(label="iteration"),) + tuple(
        uplot.Series(label=f"I{k} {what}", stroke=col(k), width=2) for k in ids)


class UpdateCurvesPanel(Panel):
    tab = "Updates"
    loss: "viser.GuiUplotHandle | None" = None
    iou: "viser.GuiUplotHandle | None" = None
    shown: int = -2

    @classmethod
    def available(cls, app: "ViewerApp") -> bool:
        return any(u.result is not None and any(r.pose is not None for r in u.result.instances)
                   for u in app.data.updates)

    def build(self, s: "Session") -> None:
        self.refresh(s, Change.COLOUR)

    def refresh(self, s: "Session", change: Change) -> None:
        if not change & Change.COLOUR:
            return
        ups = s.app.data.updates
        u = s.state.update
        if u == self.shown:
            return
        self.shown = u
        for h in (self.loss, self.iou):
            if h is not None:
                h.remove()
        self.loss = self.iou = None
        if not 0 <= u < len(ups):
            return
        x, loss, iou, ids = update_curves(ups[u])
        if not ids:
            return
        gui = s.client.gui
        assert self.tab_handle is not None
        with self.tab_handle:
            self.loss = gui.add_uplot((x, *loss), _series(ids, "loss"), title="pose loss (total)", aspect=1.6)
            self.iou = gui.add_uplot((x, *iou), _series(ids, "IoU"), title="IoU with the new mask", aspect=1.6)
