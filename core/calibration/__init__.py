"""Camera calibration from planes: Zhang, single view, pose, pattern detection, interchange."""
