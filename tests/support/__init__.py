"""Helpers the tests (and `bench/`) share, one concept a module.

Services and processes: `intspace serve` started as a user starts it (`service`), `intspace node`
started likewise with the twin's installed camera (`camera_node`), a free loopback port (`ports`),
waiting on progress or on what a test can see happen (`waiting`), a real MQTT broker
(`mqtt_broker`), a local MJPEG stream (`mjpeg_stream`), an RTSP server run by the system's Python
(`rtsp_server`), who holds PostgreSQL's advisory locks (`advisory_locks`), a copy of the migrated
SQLite template (`sqlite_copy`), the tracking service's clock held by the test (`tracker_clock`), a
stand-in scene that records the service's calls (`scene_recorder`), hostile requests and the peak
memory they cost (`hostile_requests`), a package's import graph read from its source
(`import_graph`), the dashboard signed in and driven as a user drives it (`dashboard`).

Homes, cameras and people: cameras registered through the API (`cameras`), the room of ceiling
cameras synthetic observations come from (`room`), a person walking in it (`walking_person`),
camera poses from where a camera looks (`camera_poses`), a synthetic camera network for the network
calibration (`camera_network`), the twin's network calibration stored as test data
(`twin_calibration`), Frigate's events replayed (`frigate_replay`), Home Assistant's discovery
rules (`ha_discovery`).

Reference data: synthetic chessboard photos (`chessboard_photos`), Zhang's published calibration
data (`zhang`), letter polygons for image moments (`letters`), the landmark tests' head camera and
mark poses (`landmark_views`), central-difference Jacobians of kinematic chains (`kinematics`)."""
