"""A camera node's configuration: a YAML file for many cameras, or the flags for one.

```yaml
api: http://127.0.0.1:8000/api/v1     # optional; --api wins
space: 1                              # optional: the space whose cameras these are
marker: {colour: [220, 20, 30], height: 0.36, radius: 0.05}
background_frames: 30                 # frames that teach each camera's background model
cameras:
  - name: cam_kitchen                 # the camera's name in the registry
    source: rtsp://192.168.1.20/stream1   # or 0 (USB), a file, an http(s) MJPEG URL
    fps: 10                           # detections per second at most (default: every frame)
    masks: [[[0, 0], [120, 0], [120, 80], [0, 80]]]   # pixel polygons to ignore
    detector: dnn                     # people: dnn (neural, photographs) or background
    score_threshold: 0.5              # dnn: the least score of a person's box
    min_person_px: 20                 # dnn: the least height of a person's box (px)
    flip: false                       # dnn: also detect in each tile's mirror image
    tile_px: 230                      # dnn: the tiles' side (px); smaller magnifies far people
  - name: cam_recorded
    source: /data/entrance.avi
    source_fps: 7                     # a file's true frame rate (its container may say another)
```

The people detector: `dnn` (core.localization.ssd_people, a neural detector trained on
photographs of people) for real cameras; `background` (background subtraction) for the twin's
cameras, whose people are uniformly coloured cylinders. `auto` (the default) is `background` for
the service's own camera streams (it streams the twin's cameras only) and `dnn` for every other
source.

The token is never in the file: INTSPACE_TOKEN only.
"""

from __future__ import annotations

from typing import Annotated, Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from core.errors import InvalidInput
from core.localization.ssd_people import SCORE_THRESHOLD, SsdConfig

# The intspace robot's top marker (a red disc 0.36 m above the floor): what the product's robot
# carries; a robot with another marker is configured in the file or by flags.
DEFAULT_MARKER_COLOUR = (220, 20, 30)
DEFAULT_MARKER_HEIGHT = 0.36
DEFAULT_MARKER_RADIUS = 0.05

DEFAULT_SCORE_THRESHOLD = SCORE_THRESHOLD
DEFAULT_MIN_PERSON_PX = SsdConfig.min_person_px
DEFAULT_FLIP = SsdConfig.flip
DEFAULT_TILE_PX = SsdConfig.tile_px

Vertex = Annotated[list[float], Field(min_length=2, max_length=2)]


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class MarkerConfig(_Model):
    """The robot's top marker: colour (r, g, b), height above the floor (m) and the disc's
    radius (m): a red blob is the marker only at the size and shape this disc has there."""

    colour: tuple[int, int, int] = DEFAULT_MARKER_COLOUR
    height: Annotated[float, Field(gt=0, le=5)] = DEFAULT_MARKER_HEIGHT
    radius: Annotated[float, Field(gt=0, le=1)] = DEFAULT_MARKER_RADIUS


class CameraConfig(_Model):
    """One camera: its registry name, its source, the detection rate cap, masks, how its
    stream is read (auto: httpx for the service's own MJPEG streams, OpenCV otherwise), its
    people detector and that detector's settings, and a video file's true frame rate."""

    name: Annotated[str, Field(min_length=1, max_length=200)]
    source: int | str
    fps: Annotated[float, Field(gt=0, le=240)] | None = None
    masks: list[Annotated[list[Vertex], Field(min_length=3)]] = Field(default_factory=list)
    reader: Literal["auto", "mjpeg", "opencv"] = "auto"
    realtime: bool = Field(True, description="A video file plays at its own rate, else fast.")
    detector: Literal["auto", "dnn", "background"] = "auto"
    score_threshold: Annotated[float, Field(ge=0, le=1)] | None = Field(
        default=None,
        description="The least score of a person's box; None: 0.5, the model zoo's own.",
    )
    min_person_px: Annotated[float, Field(ge=0, le=10_000)] = DEFAULT_MIN_PERSON_PX
    flip: bool = DEFAULT_FLIP
    tile_px: Annotated[int, Field(ge=2 * SsdConfig.row_overlap_px + 2, le=4096)] = Field(
        default=DEFAULT_TILE_PX,
        description="The side of the square tiles the frame is cut into for the dnn detector; "
        "the model enlarges each to 300 px, so smaller tiles find farther people at more cost.",
    )
    source_fps: Annotated[float, Field(gt=0, le=240)] | None = Field(
        default=None,
        description="A video file's frame rate: frame k is captured at t0 + k / source_fps "
        "and, in real time, played at that rate (a container's own rate can be wrong).",
    )


class NodeConfig(_Model):
    """Everything a node runs with."""

    api: str | None = None
    space: Annotated[int, Field(ge=1)] | None = None
    marker: MarkerConfig = MarkerConfig()
    background_frames: Annotated[int, Field(ge=0, le=10_000)] = 30
    cameras: Annotated[list[CameraConfig], Field(min_length=1)]


def load_config(text: str) -> NodeConfig:
    """Return the configuration of a YAML document. Raises InvalidInput naming the field."""
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise InvalidInput(f"not valid YAML: {exc}") from exc
    if not isinstance(data, dict):
        raise InvalidInput("the configuration must be a mapping with a 'cameras' list")
    try:
        config = NodeConfig.model_validate(data)
    except ValidationError as exc:
        first = exc.errors()[0]
        where = ".".join(str(p) for p in first["loc"])
        raise InvalidInput(f"{where}: {first['msg']}") from exc
    names = [c.name for c in config.cameras]
    if len(set(names)) != len(names):
        raise InvalidInput("each camera may appear once in 'cameras'")
    return config


def parse_source(value: str) -> int | str:
    """Return a USB index for a string of digits, the string otherwise."""
    return int(value) if value.strip().isdigit() else value
