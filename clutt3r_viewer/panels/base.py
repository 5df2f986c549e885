"""The interface every panel implements, and how the session uses it.

A panel is a small class that owns its GUI handles and scene nodes as typed attributes.
``Session.build`` creates the panels of ``PANELS`` whose ``available(app)`` is true, in
order, each inside its tab (``tab``; None = above the tabs), and calls ``build(session)``.
When a tab's state changes, ``Session.changed(change)`` calls every panel's
``refresh(session, change)``; a panel updates what depends on that ``Change`` and ignores
the rest. Actions a panel offers (a slider, a button) change ``session.state`` under
``session.lock`` and then call ``session.changed``.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, ClassVar

from clutt3r_viewer.state import Change

if TYPE_CHECKING:
    import viser

    from clutt3r_viewer.app import Session, ViewerApp

__all__ = ["Panel", "Change", "IMAGE_MAX_WIDTH", "downscale_step"]

IMAGE_MAX_WIDTH = 480  # GUI image width in pixels (the panel is ~350 px wide; 480 stays sharp on HiDPI)


def downscale_step(width: int, max_width: int) -> int:
    """Integer stride that brings ``width`` pixels to at most ``max_width``."""
    return max(1, -(-int(width) // int(max_width)))


class Panel:
    """Base class of the viewer's panels (module docstring)."""

    tab: ClassVar[str | None] = None
    """Title of the tab the panel lives in (panels may share a tab); None = above the tabs."""

    tab_handle: "viser.GuiTabHandle | None" = None
    """Set by the session before ``build``: re-enter it to add widgets to this tab later."""

    @classmethod
    def available(cls, app: "ViewerApp") -> bool:
        """Whether the run has what this panel shows (panels for absent data are not built)."""
        return True

    def build(self, s: "Session") -> None:
        raise NotImplementedError

    def refresh(self, s: "Session", change: Change) -> None:
        """Update what depends on ``change``; called inside ``client.atomic()`` with ``s.lock`` held."""
