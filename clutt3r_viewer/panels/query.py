"""The Query tab: rank instances by a text query (shown only when the run's embedder embeds text)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from clutt3r_viewer.panels.base import Change, Panel

if TYPE_CHECKING:
    import viser

    from clutt3r_viewer.app import Session, ViewerApp

__all__ = ["QueryPanel"]


class QueryPanel(Panel):
    tab = "Query"
    query: "viser.GuiTextHandle"
    find: "viser.GuiButtonHandle"
    result: "viser.GuiMarkdownHandle"

    @classmethod
    def available(cls, app: "ViewerApp") -> bool:
        return app.text_embedder is not None

    def build(self, s: "Session") -> None:
        gui = s.client.gui
        self.query = gui.add_text("Query", "")
        self.find = gui.add_button("Find")
        self.find.on_click(lambda ev: self.run_query(s, self.query.value))
        self.query.on_update(lambda ev: self.run_query(s, self.query.value))
        self.result = gui.add_markdown(f"_text embedder: `{s.app.text_embedder.name}`_")

    def run_query(self, s: "Session", text: str) -> None:
        """Score every instance against ``text``; the best one is highlighted (``query`` colour layer)."""
        with s.lock:
            text = text.strip()
            st = s.state
            st.query = text
            if not text:
                st.query_best, st.query_scores = -1, None
                self.result.content = "_empty query_"
                if st.color_mode == "query":
                    st.color_mode = "instance"
                s.changed(Change.COLOUR)
                return
            emb = s.app.text_embedder.embed_text([text])[0]
            scores = s.app.data.instance_text_scores(emb)
            if len(scores) == 0:
                st.query_best, st.query_scores = -1, None
                self.result.content = "_no instances_"
                s.changed(Change.COLOUR)
                return
            order = np.argsort(-scores)
            st.query_best, st.query_scores = int(order[0]), scores
            st.color_mode = "query"
            self.result.content = "\n".join(
                [f"**{text}** → I{int(order[0])}", "", "| inst | score |", "|---|---|"]
                + [f"| I{int(k)} | {scores[k]:.3f} |" for k in order[:8]])
            s.changed(Change.COLOUR)
