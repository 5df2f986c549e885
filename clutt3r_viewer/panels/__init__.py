"""The viewer's panels, one module each; ``PANELS`` is the order the session builds them in.

Tabs appear in the order of their first panel. Add a panel by subclassing ``Panel``
(``panels/base.py``) and appending the class here (or to ``PANELS`` from your own code
before the server starts); see docs/architecture.md.
"""

from __future__ import annotations

from clutt3r_viewer.panels.base import Change, Panel
from clutt3r_viewer.panels.edit import EditPanel
from clutt3r_viewer.panels.explain import ExplainPanel
from clutt3r_viewer.panels.graph import LeafGraphPanel
from clutt3r_viewer.panels.grasps import GraspsPanel
from clutt3r_viewer.panels.query import QueryPanel
from clutt3r_viewer.panels.replay import ReplayPanel
from clutt3r_viewer.panels.scene import InstancesPanel, ScenePanel
from clutt3r_viewer.panels.tree import TreePanel
from clutt3r_viewer.panels.tour import ShareHtmlPanel, TourPanel
from clutt3r_viewer.panels.updates import UpdatesPanel
import clutt3r_viewer.panels.update_sources  # noqa: E402,F401  (registers the update chain's frames and pose replay)
from clutt3r_viewer.panels.update_curves import UpdateCurvesPanel
from clutt3r_viewer.panels.views import ViewsPanel
from clutt3r_viewer.panels.warnings import WarningsPanel

__all__ = ["Panel", "Change", "PANELS", "ViewsPanel", "ScenePanel", "InstancesPanel", "TreePanel", "LeafGraphPanel",
           "ReplayPanel", "QueryPanel", "EditPanel", "GraspsPanel", "UpdatesPanel", "WarningsPanel", "TourPanel",
           "ShareHtmlPanel"]

PANELS: list[type[Panel]] = [ViewsPanel, WarningsPanel, ScenePanel, InstancesPanel, ShareHtmlPanel, TreePanel, LeafGraphPanel,
                             ReplayPanel, ExplainPanel, QueryPanel, EditPanel, GraspsPanel, UpdatesPanel, UpdateCurvesPanel,
                             TourPanel]  # last: it drives the others; its folder is ordered above them
