"""``clutt3r synth``: writes a loadable scene folder."""

from __future__ import annotations

from clutt3r_core.io.sample_layout import load_sample_layout
from clutt3r_core.synth.cli import synth_command


def test_synth_command_writes_scene(tmp_path, capsys):
    synth_command(tmp_path / "s", seed=2, views=2, width=160, height=120, n_objects=3, mask_noise="clean")
    s = load_sample_layout(tmp_path / "s")
    assert len(s.views) == 2 and s.ground_truth is not None and len(s.ground_truth.objects) == 3
    assert (tmp_path / "s" / "contact_sheet.png").is_file()
    assert "mean occlusion" in capsys.readouterr().out
