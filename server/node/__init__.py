"""The camera node (`intspace node`): reads cameras, detects in their frames with
core.localization.detections.detect_frame and posts the detections to the service (spec 08).

Pure pieces (no I/O): `mjpeg` (multipart parser), `frames` (newest-frame holder), `masks`,
`clock` (offset to the service's clock), `config` (the YAML file). I/O: `sources` (reader
threads), `client` (the service's REST API), `runner` (one node's threads).
"""
