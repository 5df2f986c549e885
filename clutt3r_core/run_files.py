"""Names of files in a run folder that modules of different weight read (``runs.py`` describes
the folder). No imports: ``clutt3r update`` reads the correction log's path at start-up
(``update.run_labels``) without loading the correction modules that write it
(``annotations``, ``corrections``)."""

__all__ = ["CORRECTION_LOG"]

CORRECTION_LOG = "corrections/ops.jsonl"
"""The Edit tab's append-only correction log (``annotations``, docs/corrections.md)."""
