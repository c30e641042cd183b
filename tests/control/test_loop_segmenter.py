"""The loop's segmenter option: the classical default, the learned CNN on request, bad names refused."""

from __future__ import annotations

from pathlib import Path

import gymnasium as gym
import pytest

from dyndlo_vision.cli import main
from dyndlo_vision.control.sim_perception import tracked_state
from dyndlo_vision.tracking.learned import LearnedSegmenter
from dyndlo_vision.tracking.segmentation import BackgroundSegmenter


def test_tracked_state_segmenters() -> None:
    env = gym.make("DynDLO/TipControl-v0", multi_step=True)
    try:
        env.reset(seed=0)
        with pytest.raises(ValueError, match="'bogus'"):
            tracked_state(env, segmenter="bogus")
        for name, kind in (("background", BackgroundSegmenter), ("learned", LearnedSegmenter)):
            source, camera = tracked_state(env, segmenter=name)
            try:
                segmenter = source.tracker.segmenter
                assert isinstance(segmenter.base, kind)
                mask = segmenter(camera.read().rgb)
                assert mask.shape == (480, 640) and mask.any()
            finally:
                camera.close()
    finally:
        env.close()


def test_demo_segmenter_needs_tracked_state(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        main(["demo", "--observation", "true", "--segmenter", "learned", "--out", str(tmp_path / "d")])
    assert exc.value.code == 2
    assert "--segmenter" in capsys.readouterr().err
    assert not (tmp_path / "d").exists()
