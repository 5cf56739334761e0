"""Application services: authentication, calibration runs, the scene, pose conversions."""
