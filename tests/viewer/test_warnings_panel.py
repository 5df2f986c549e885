"""The run summary shows the run's warnings (issue 14), checked server-side: a websocket client
speaking viser's protocol opens a real session, no browser."""

from __future__ import annotations

import json
import shutil
import threading

import pytest

from clutt3r_core.diagnostics import RunWarning
from clutt3r_core.runs import read_run_info
from clutt3r_viewer.panels import PANELS
from clutt3r_viewer.panels.warnings import WarningsPanel, warnings_markdown
from tests.viewer.conftest import free_port

WARNINGS = [
    {"code": "frame-demoted", "frame": 5, "view": "image_000005.png",
     "message": "frame 5 (image_000005.png): its depth file depth/depth_000005.png is missing, so it was taken "
                "as a post-interaction frame and is not segmented"},
    {"code": "depth-invalid", "frame": 2, "view": "image_000002.png",
     "message": "frame 2: 73 % of its depth pixels are holes or out of range"},
    {"code": "view-no-masks", "frame": None, "view": "", "message": "a view has no mask candidate"},
]


def test_warnings_markdown_names_code_frame_view_and_message():
    ws = tuple(RunWarning(**w) for w in WARNINGS)
    md = warnings_markdown(ws)
    lines = md.splitlines()
    assert len(lines) == 3 and all(ln.startswith("- `") for ln in lines)
    assert lines[0].startswith("- `frame-demoted` (frame 5, image\\_000005.png): frame 5")
    assert "depth/depth\\_000005.png is missing" in lines[0]  # markdown would eat the underscores
    assert lines[2] == "- `view-no-masks`: a view has no mask candidate"  # no frame, no view: nothing in brackets
    assert warnings_markdown(()) == ""


def camera_message() -> bytes:
    """A browser's first camera message, as viser's client sends it (msgpack of the message's dict)."""
    import msgspec
    from viser import _messages

    msg = _messages.ViewerCameraMessage(wxyz=(1.0, 0.0, 0.0, 0.0), position=(0.0, 0.0, 1.0), fov=1.0, near=0.01,
                                        far=100.0, image_height=800, image_width=1280, look_at=(0.0, 0.0, 0.0),
                                        up_direction=(0.0, 0.0, 1.0))
    return msgspec.msgpack.encode(msg.as_serializable_dict())


class _Tab:
    """One viser websocket client that reads and discards every message (a tab without rendering)."""

    def __init__(self, url: str) -> None:
        import viser
        from websockets.sync.client import connect

        self.ws = connect(url.replace("http://", "ws://"), subprotocols=[f"viser-v{viser.__version__}"],
                          max_size=None, open_timeout=30)
        self.ws.send(camera_message())  # viser counts a client as connected at its first camera message
        self.thread = threading.Thread(target=self._read, daemon=True)
        self.thread.start()

    def _read(self) -> None:
        try:
            for _ in self.ws:
                pass
        except Exception:  # closed by the test or the server
            pass

    def close(self) -> None:
        self.ws.close()
        self.thread.join(timeout=10)


@pytest.mark.parametrize("warned", [True, False])
def test_viewer_shows_the_runs_warnings_above_the_tabs(tiny_run_dir, tmp_path, warned):
    import clutt3r_viewer

    run = shutil.copytree(tiny_run_dir, tmp_path / "run")
    info = json.loads((run / "run.json").read_text())
    info["warnings"] = WARNINGS if warned else []
    (run / "run.json").write_text(json.dumps(info))
    assert len(read_run_info(run).warnings) == (3 if warned else 0)
    app = clutt3r_viewer.start(run, port=free_port())
    tab = None
    try:
        tab = _Tab(app.url)
        (s,) = app.wait_for_sessions(1, timeout=60)
        p = s.panel(WarningsPanel)
        if not warned:
            assert p is None  # a clean run shows nothing extra
            return
        assert p is not None and PANELS.index(WarningsPanel) == 1 and WarningsPanel.tab is None  # under the title
        assert p.folder.label == "Run warnings (3)"
        md = p.text.content
        for w in WARNINGS:
            assert f"`{w['code']}`" in md
        assert "frame 5, image\\_000005.png" in md and "73 % of its depth pixels" in md
        assert md == warnings_markdown(read_run_info(run).warnings)
    finally:
        if tab is not None:
            tab.close()
        app.stop()
