"""The run's warnings (issue 14: "no silent degradation"), above the tabs under the title.

What degraded the run's input (a frame demoted to post-interaction, a view dropped, a view
with mostly invalid depth, a view that sees none of the others, a view without masks) is
recorded in the run (``run.json``: ``clutt3r_core.runs.read_run_info(run).warnings``, read back
by ``load_run`` as ``Segmentation.warnings``; a scene segmented by the viewer has them too).
The panel is built only when there is at least one, so a clean run shows nothing extra.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from clutt3r_viewer.panels.base import Panel

if TYPE_CHECKING:
    import viser

    from clutt3r_core.diagnostics import RunWarning
    from clutt3r_viewer.app import Session, ViewerApp

__all__ = ["WarningsPanel", "warnings_markdown"]


def _md(text: str) -> str:
    """``text`` with the characters markdown would interpret escaped (messages name files like ``depth_000005.png``)."""
    for c in "\\`*_[]<>|":
        text = text.replace(c, "\\" + c)
    return text


def warnings_markdown(warnings: "tuple[RunWarning, ...]") -> str:
    """One markdown list item per warning: code, frame and view, then its message."""
    lines = []
    for w in warnings:
        where = []
        if w.frame is not None:
            where.append(f"frame {w.frame}")
        if w.view:
            where.append(_md(w.view))
        lines.append(f"- `{w.code}`" + (f" ({', '.join(where)})" if where else "") + f": {_md(w.message)}")
    return "\n".join(lines)


class WarningsPanel(Panel):
    """Above the tabs: the run's warnings, in a folder titled with their count."""

    tab = None
    folder: "viser.GuiFolderHandle"
    text: "viser.GuiMarkdownHandle"

    @classmethod
    def available(cls, app: "ViewerApp") -> bool:
        return bool(app.data.seg.warnings)

    def build(self, s: "Session") -> None:
        ws = s.app.data.seg.warnings
        n = len(ws)
        # open: a warning nobody sees is a silent degradation again
        with s.client.gui.add_folder(f"Run warnings ({n})", expand_by_default=True) as self.folder:
            self.text = s.client.gui.add_markdown(warnings_markdown(ws))
