"""``benchmarks/segmentation_generalisation.py --quick`` runs, and reports every kind of scene on its own."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from dyndlo_vision.learning.segdata import STYLES

ROOT = Path(__file__).resolve().parents[2]
EXTERNAL = ROOT.parent / "shared" / "data" / "external"


@pytest.mark.slow
def test_the_quick_benchmark_reports_every_kind(tmp_path: Path) -> None:
    out = tmp_path / "seg.json"
    worst = tmp_path / "worst"
    subprocess.run([sys.executable, str(ROOT / "benchmarks" / "segmentation_generalisation.py"), "--quick",
                    "--parts", "external,labels,styles,flat,speed", "--external", str(EXTERNAL),
                    "--worst", str(worst), "--out", str(out)], check=True, cwd=ROOT, timeout=600)
    report = json.loads(out.read_text())
    assert report["quick"] is True
    assert set(report["styles"]) == set(STYLES)
    for style, entry in report["styles"].items():
        assert entry["n"] + entry["no_cable_samples"] == 2, style
        assert 0.0 <= entry["dice_mean"] <= 1.0 and 0.0 <= entry["near_empty_share"] <= 1.0
        # Forgiving boundaries a pixel off can only raise each image's figure.
        assert all(r["dice"] <= r["dice_1px"] <= 1.0 for r in entry["rows"]), style
        # Where the figure is lost: the loss shares add up with DICE to 1, per image and per kind.
        for r in entry["rows"]:
            assert abs(r["dice"] + sum(r["losses"].values()) - 1.0) < 1e-9, style
            assert all(r["found_px"][b] <= r["true_px"][b] for b in r["true_px"]), style
        if entry["n"]:
            assert abs(entry["dice_mean"] + sum(entry["loss_mean"].values()) - 1.0) < 1e-9, style
            assert abs(sum(entry["true_px_share"].values()) - 1.0) < 1e-9, style
        assert (worst / f"worst_{style}.png").is_file()
    assert report["speed"]["learned_ms"] > 0
    if EXTERNAL.is_dir():  # both sources, both halves, each on its own
        summary = report["external"]["summary"]
        for source in ("mbest", "cables_dataset"):
            for half in ("heldout", "train"):
                kind = summary[f"{source}/{half}"]
                assert kind["n"] == 2
                assert 0.0 <= kind["near_empty_share"] <= 1.0
                assert kind["dice_mean"] <= kind["dice_1px_mean"]
        for source in ("mbest", "cables_dataset"):
            labels = report["labels"][source]
            assert labels["profiles"] > 0, source
            assert 0.0 < labels["dice_1d_mean"] <= 1.0
            assert labels["photo_width_px_p10_p50_p90"] == sorted(labels["photo_width_px_p10_p50_p90"])
            for half in ("heldout", "train"):
                against_photo = labels["mask_vs_photo"][half]
                assert against_photo["profiles"] > 0
                assert 0.0 <= against_photo["mask_dice_1d_mean"] <= 1.0
