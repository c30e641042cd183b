"""Camera-based cable tracking: camera model, segmentation, ordered centreline, 3D lifting
and Kalman filtering of cable points, and two-view triangulation of the centreline (pure computation, no
MuJoCo needed).

Typical use, per camera frame (RGB uint8)::

    from dyndlo_vision.tracking.pipeline import CablePipeline, PipelineConfig
    from dyndlo_vision.tracking.segmenters import build_segmenter, build_view_segmenter

    cam = PinholeCamera.from_json("camera.json")
    config = PipelineConfig(plane=Plane(np.array([0.0, 0.0, 1.0]), 0.0))  # tracking.params: why each default
    base, _ = build_segmenter(config.segmenter)
    segmenter = build_view_segmenter(base, max_width_share=config.max_width_share,
                                     max_width_ratio=config.max_width_ratio)
    pipeline = CablePipeline(config, [cam], [segmenter], anchors=[(320, 40)])
    result = pipeline.step([rgb], t_capture)    # result.status: measured, continued, predicted or lost
    est = pipeline.estimate(t_now)              # latency-compensated read

The names below load their submodule on first use, so importing the package (e.g. for
:class:`FilterParams` in a command's ``--help``) loads neither OpenCV nor SciPy nor filterpy.

Speed (one core, 640x480): ``python benchmarks/tracking_speed.py``.
"""

# ruff: noqa: F401  (the TYPE_CHECKING block re-exports for type checkers only)
from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

#: Public name -> the submodule that defines it.
_EXPORTS = {
    "annotate_frame": "annotate",
    "covariance_ellipse": "annotate",
    "project_point_covariance": "annotate",
    "CalibrationError": "camera_model",
    "PinholeCamera": "camera_model",
    "Centerline": "centerline",
    "CenterlineParams": "centerline",
    "Measurement2D": "centerline",
    "extract_centerline": "centerline",
    "polyline_distance": "centerline",
    "resample_polyline": "centerline",
    "thin": "centerline",
    "thin_coords": "centerline",
    "Estimate": "filter",
    "MultiEstimate": "filter",
    "MultiPointFilter": "filter",
    "PointFilter": "filter",
    "FilterParams": "params",
    "LATENT_LOOP_FILTER": "params",
    "LOOP_FILTER": "params",
    "BackgroundSegmenter": "segmentation",
    "clean_mask": "segmentation",
    "dice": "segmentation",
    "cable_widths": "segmentation",
    "dice_losses": "segmentation",
    "dice_within": "segmentation",
    "segment_hsv": "segmentation",
    "StereoParams": "stereo",
    "essential_matrix": "stereo",
    "match_centerlines": "stereo",
    "nodes_by_arc_length": "stereo",
    "stereo_measurement": "stereo",
    "triangulate": "stereo",
    "Measurement": "tracker",
    "Plane": "tracker",
    "lift_with_depth": "tracker",
    "lift_with_plane": "tracker",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f"{__name__}.{module}"), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))


if TYPE_CHECKING:  # the same names for type checkers (tests/tracking/test_package.py checks the two agree)
    from .annotate import annotate_frame, covariance_ellipse, project_point_covariance
    from .camera_model import CalibrationError, PinholeCamera
    from .centerline import (
        Centerline,
        CenterlineParams,
        Measurement2D,
        extract_centerline,
        polyline_distance,
        resample_polyline,
        thin,
        thin_coords,
    )
    from .filter import Estimate, MultiEstimate, MultiPointFilter, PointFilter
    from .params import LATENT_LOOP_FILTER, LOOP_FILTER, FilterParams
    from .segmentation import (
        BackgroundSegmenter,
        cable_widths,
        clean_mask,
        dice,
        dice_losses,
        dice_within,
        segment_hsv,
    )
    from .stereo import (
        StereoParams,
        essential_matrix,
        match_centerlines,
        nodes_by_arc_length,
        stereo_measurement,
        triangulate,
    )
    from .tracker import Measurement, Plane, lift_with_depth, lift_with_plane
