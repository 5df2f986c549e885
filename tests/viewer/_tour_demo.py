"""The tiny demo run the tour tests share (built once per test session, then read back from its
demo.json by ``build_demo``'s cache: a second fixture call costs a file read).

Seed 7 of the 'easy' preset at 4 views 320x240: the update reports the object the generator took
away as removed and re-poses the one it pushed (measured: ``/tmp``-free scan of seeds 0-7, only
3 and 7 re-pose the pushed object, only 7 also finds the removed one), so every tour step has
something to show.
"""

from __future__ import annotations

from pathlib import Path

from clutt3r_core.demo import DemoConfig

TINY = DemoConfig(seed=7, preset="easy", views=4, width=320, height=240, focal_px=200.0, top_grasps=5)


def language_available() -> bool:
    try:
        from clutt3r_core.query import create_grounder

        create_grounder()
        return True
    except Exception:  # noqa: BLE001  (any failure: the query steps are skipped with a reason)
        return False


def tiny_demo_dir(tmp_path_factory) -> Path:
    from clutt3r_core.demo import build_demo

    out = tmp_path_factory.getbasetemp() / "tour_demo" / "run"
    build_demo(out, TINY, with_query=language_available(), log=lambda s: None)
    return out
