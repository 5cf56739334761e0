"""Helpers the tests share: waiting on a run's progress (`waiting`), the twin's network
calibration stored as test data (`twin_calibration`), a package's import graph read from its
source (`import_graph`)."""
