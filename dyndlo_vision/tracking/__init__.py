"""Camera-based cable tracking: camera model, segmentation, ordered centreline, 3D lifting
and Kalman filtering of cable points (pure computation, no MuJoCo needed).

Typical use, per camera frame (RGB uint8)::

    cam = PinholeCamera.from_json("camera.json")
    tracker = CableTracker(cam, plane=Plane(np.array([0.0, 0.0, 1.0]), 0.0), anchor_uv=(320, 40))
    tip = PointFilter(sigma_accel=20.0, sigma_meas=0.003)
    meas = tracker.process(rgb, t_capture)
    tip.update(meas.point(-1), t_capture)      # None (tip not seen) coasts
    est = tip.estimate(t_now)                   # latency-compensated read

Speed (one core, 640x480): ``python benchmarks/tracking_speed.py``.
"""

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
)
from .filter import Estimate, MultiEstimate, MultiPointFilter, PointFilter
from .segmentation import BackgroundSegmenter, clean_mask, dice, segment_hsv
from .tracker import CableTracker, Measurement, Plane, lift_with_depth, lift_with_plane

__all__ = [
    "BackgroundSegmenter",
    "annotate_frame",
    "covariance_ellipse",
    "project_point_covariance",
    "CableTracker",
    "CalibrationError",
    "Centerline",
    "CenterlineParams",
    "Estimate",
    "Measurement",
    "Measurement2D",
    "MultiEstimate",
    "MultiPointFilter",
    "PinholeCamera",
    "Plane",
    "PointFilter",
    "clean_mask",
    "dice",
    "extract_centerline",
    "lift_with_depth",
    "lift_with_plane",
    "polyline_distance",
    "resample_polyline",
    "segment_hsv",
    "thin",
]
