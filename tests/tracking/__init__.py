"""Tests of dyndlo_vision.tracking: camera model, segmentation, centreline, tracker, filter, metrics, CLIs."""
