"""Helpers the tests (and `bench/`) share: `intspace serve` started as a user starts it (`service`),
a free loopback port (`ports`), waiting on a run's progress (`waiting`), the twin's network
calibration stored as test data (`twin_calibration`), a package's import graph read from its source
(`import_graph`), cameras registered through the API (`cameras`), synthetic chessboard photos
(`chessboard_photos`), a real MQTT broker (`mqtt_broker`), Frigate's events replayed
(`frigate_replay`), Home Assistant's discovery rules (`ha_discovery`), a local MJPEG stream
(`mjpeg_stream`), an RTSP server run by the system's Python (`rtsp_server`)."""
