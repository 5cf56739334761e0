"""Small shared geometry: rotations, point normalisation, the camera model."""
