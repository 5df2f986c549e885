"""Mask candidates per view: the ``MaskGenerator`` backend kind (registry kind ``mask_generator``).

The method needs noisy, overlapping, hierarchical candidates per view (the paper prompts
Grounded SAM with "object"). A generator turns one posed RGB-D view into
``MaskCandidates``; the pipeline builds each view's containment tree from them.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

from clutt3r_core.scene import MaskCandidates, View

__all__ = ["MaskGenerator"]


@runtime_checkable
class MaskGenerator(Protocol):
    """Makes mask candidates for one view."""

    name: str

    def generate(self, view: View) -> MaskCandidates:
        """-> candidates of the view's image size (ids 0..M-1, any overlap allowed)."""
        ...
