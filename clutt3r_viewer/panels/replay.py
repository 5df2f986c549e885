"""The Replay tab: step through any ordered event source (``clutt3r_viewer.events``)."""

from __future__ import annotations

import threading
import time
from typing import TYPE_CHECKING

from clutt3r_viewer.panels.base import Change, Panel

if TYPE_CHECKING:
    import viser

    from clutt3r_viewer.app import Session, ViewerApp

__all__ = ["ReplayPanel"]


class ReplayPanel(Panel):
    """A slider over the steps of the selected event source, Play/Pause, and the step's text.

    Moving the slider switches the cloud to the ``replay`` colour layer.
    """

    tab = "Replay"
    source: "viser.GuiDropdownHandle[str] | None" = None  # only when the run has more than one source
    event: "viser.GuiSliderHandle[int]"
    play: "viser.GuiButtonHandle"
    text: "viser.GuiMarkdownHandle"

    @classmethod
    def available(cls, app: "ViewerApp") -> bool:
        return len(app.sources) > 0

    def build(self, s: "Session") -> None:
        gui = s.client.gui
        names = [src.name for src in s.app.sources]
        if len(names) > 1:
            self.source = gui.add_dropdown("Events", names, initial_value=s.state.replay_source)
            self.source.on_update(lambda ev: self.set_source(s, self.source.value))
        src = s.replay_source()
        ne = src.num_events if src is not None else 0
        self.event = gui.add_slider("Event", 0, max(ne, 1), 1, 0, disabled=ne == 0)
        self.event.on_update(lambda ev: self.set_event(s, int(self.event.value)))
        self.play = gui.add_button("Play", icon=None)
        self.play.on_click(lambda ev: self.toggle_play(s))
        self.text = gui.add_markdown(src.text(0) if src is not None else "")

    # -- actions -------------------------------------------------------------------------

    def set_source(self, s: "Session", name: str) -> None:
        with s.lock:
            if name == s.state.replay_source:
                return
            s.state.replay_source = name
            s.state.event = 0
            src = s.replay_source()
            ne = src.num_events if src is not None else 0
            with s.client.atomic():
                self.event.max = max(ne, 1)
                self.event.disabled = ne == 0
                s.state.color_mode = "replay"
                s.changed(Change.COLOUR)

    def set_event(self, s: "Session", n: int) -> None:
        with s.lock:
            if n == s.state.event and s.state.color_mode == "replay":
                return
            s.state.event = int(n)
            s.state.color_mode = "replay"
            s.changed(Change.COLOUR)

    def toggle_play(self, s: "Session") -> None:
        with s.lock:
            s.state.playing = not s.state.playing
            self.play.label = "Pause" if s.state.playing else "Play"
            if s.state.playing:
                src = s.replay_source()
                if src is not None and s.state.event >= src.num_events:
                    self.set_event(s, 0)
                threading.Thread(target=self._play_loop, args=(s,), daemon=True).start()

    def _play_loop(self, s: "Session") -> None:
        while s.state.playing and not s.closed:
            time.sleep(s.app.play_interval)
            with s.lock:
                if not s.state.playing:
                    break
                src = s.replay_source()
                n = s.state.event + 1
                if src is None or n > src.num_events:
                    s.state.playing = False
                    self.play.label = "Play"
                    break
                self.set_event(s, n)

    # -- display -------------------------------------------------------------------------

    def refresh(self, s: "Session", change: Change) -> None:
        if not change & Change.COLOUR:
            return
        n = s.state.event
        if int(self.event.value) != n:
            self.event.value = n
        if self.source is not None and self.source.value != s.state.replay_source:
            self.source.value = s.state.replay_source
        src = s.replay_source()
        self.text.content = src.text(n) if src is not None else ""
