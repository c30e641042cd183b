"""The main job, `dyndlo-vision demo`, end to end on its shipped defaults."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import pytest

from dyndlo_vision.cli import main


@pytest.mark.slow
def test_demo_writes_video_plot_and_metrics(tmp_path: Path) -> None:
    out = tmp_path / "demo"
    assert main(["demo", "--out", str(out)]) == 0
    metrics = json.loads((out / "metrics.json").read_text())
    for key in ("success", "final_distance_m", "estimate_rmse_m", "cycle_ms_p50", "cycle_ms_p95"):
        assert key in metrics
    assert metrics["observation"] == "tracked" and metrics["cycles"] > 20
    assert 0.0 < metrics["estimate_rmse_m"] < 0.1  # measured 19 mm on this seed
    video = cv2.VideoCapture(str(out / "demo.mp4"))
    assert int(video.get(cv2.CAP_PROP_FRAME_COUNT)) == metrics["cycles"]
    plot = cv2.imread(str(out / "p_dlo.png"))
    assert plot is not None and plot.shape[0] > 300


def test_demo_rejects_bad_input_and_writes_nothing(tmp_path: Path) -> None:
    out = tmp_path / "demo"
    for argv in (["--episodes", "0"], ["--policy", str(tmp_path / "missing.zip")]):
        with pytest.raises(SystemExit) as exc:
            main(["demo", "--out", str(out), *argv])
        assert exc.value.code == 2
    assert not out.exists() or not any(out.iterdir())
