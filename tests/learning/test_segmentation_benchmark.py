"""``benchmarks/segmentation_generalisation.py --quick`` runs, and reports every kind of scene on its own."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
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
        if entry["n"] == 2:  # the standard error of a mean of two: half their difference
            d = [r["dice"] for r in entry["rows"]]
            assert abs(entry["dice_se"] - abs(d[0] - d[1]) / 2) < 1e-12, style
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


def _benchmark():  # type: ignore[no-untyped-def]
    sys.path.insert(0, str(ROOT / "benchmarks"))
    import segmentation_generalisation

    return segmentation_generalisation


def _report(external: dict[str, float], styles: dict[str, dict[str, float]], true_px: int = 100) -> dict:
    px = {"thin": 10, "mid": 20, "wide": true_px - 30}
    rows = [{"source": k.split("/")[0], "image": k.split("/", 1)[1], "split": "heldout", "dice": v,
             "true_px": px} for k, v in external.items()]
    by_style = {s: {"rows": [{"image": i, "dice": v, "true_px": px} for i, v in r.items()]}
                for s, r in styles.items()}
    return {"external": {"rows": rows}, "styles": by_style}


def test_paired_differences_match_images_by_name_within_each_kind() -> None:
    sg = _benchmark()
    a = _report({"mbest/a.jpg": 0.9, "mbest/b.jpg": 0.8, "cables_dataset/c.png": 0.7},
                {"busy": {"000000": 0.5, "000001": 0.6, "000002": 0.9}, "wires": {"000000": 0.4}})
    b = _report({"mbest/b.jpg": 0.7, "mbest/a.jpg": 0.6},
                {"busy": {"000001": 0.5, "000000": 0.2, "000003": 0.1}, "harness": {"000000": 0.4}})
    out = sg.paired(a, b)
    assert set(out) == {"mbest/heldout", "busy"}, "kinds with no image in common are left out"
    assert out["mbest/heldout"]["n"] == 2
    assert out["mbest/heldout"]["dice_diff_mean"] == pytest.approx(0.2)  # 0.3 and 0.1
    assert out["mbest/heldout"]["dice_diff_se"] == pytest.approx(0.1)
    assert out["busy"]["n"] == 2 and out["busy"]["dice_diff_mean"] == pytest.approx(0.2)  # 0.3 and 0.1
    # The same image names in another kind are other images.
    c = _report({}, {"wires": {"000000": 0.5, "000001": 0.6}})
    with pytest.raises(ValueError, match="no image scored in both reports"):
        sg.paired(c, _report({}, {"busy": {"000000": 0.5, "000001": 0.6}}))
    assert sg.paired(c, c)["wires"] == {"n": 2, "dice_diff_mean": 0.0, "dice_diff_se": 0.0}
    assert sg.paired(_report({}, {"wires": {"000000": 0.5}}), c)["wires"]["dice_diff_se"] is None
    # Other scenes under the same names (a development and a test folder both called wires).
    with pytest.raises(ValueError, match="wires 000000: 100 true cable pixels here and 90 in the other"):
        sg.paired(c, _report({}, {"wires": {"000000": 0.5, "000001": 0.6}}, true_px=90))


def test_standard_error_of_the_mean() -> None:
    sg = _benchmark()
    assert sg._standard_error([1.0, 2.0, 3.0, 4.0]) == pytest.approx(np.std([1, 2, 3, 4], ddof=1) / 2)
    assert sg._standard_error([0.5]) is None


@pytest.mark.parametrize("content", ["not json", "[1, 2]", '{"model": "x"}'])
def test_a_bad_against_report_is_refused_before_scoring(tmp_path: Path, content: str) -> None:
    bad = tmp_path / "other.json"
    bad.write_text(content)
    out = tmp_path / "seg.json"
    res = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "segmentation_generalisation.py"),
                          "--parts", "styles", "--against", str(bad), "--out", str(out)],
                         cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert res.returncode != 0 and f"--against {bad}" in res.stderr
    assert not out.exists()


def test_scores_are_written_when_the_against_report_pairs_nothing(tmp_path: Path) -> None:
    other = tmp_path / "other.json"
    other.write_text(json.dumps(_report({}, {"harness": {"000000": 0.5}})))
    out = tmp_path / "seg.json"
    res = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "segmentation_generalisation.py"),
                          "--quick", "--parts", "styles", "--styles", "wires", "--against", str(other),
                          "--out", str(out)], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert res.returncode != 0 and "no image scored in both reports" in res.stderr
    report = json.loads(out.read_text())
    assert set(report["styles"]) == {"wires"} and "paired" not in report
