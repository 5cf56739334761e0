"""Home Assistant's MQTT discovery schema, as its documentation states it (home-assistant.io:
"MQTT Discovery", "MQTT Binary sensor", "MQTT Sensor"), for checking the configs the service
publishes: the topic's form, the keys each component accepts, the required ones and the types."""

from __future__ import annotations

import re
from typing import Any

# <discovery_prefix>/<component>/[<node_id>/]<object_id>/config; node_id and object_id
# "must match [a-zA-Z0-9_-]+".
TOPIC = re.compile(
    r"^(?P<prefix>[^/#+]+)/(?P<component>[a-z_]+)/(?:(?P<node_id>[a-zA-Z0-9_-]+)/)?"
    r"(?P<object_id>[a-zA-Z0-9_-]+)/config$"
)

# Keys common to the entities (availability, device, naming and ids), with their types.
COMMON: dict[str, type | tuple[type, ...]] = {
    "availability_topic": str,
    "payload_available": str,
    "payload_not_available": str,
    "availability_mode": str,
    "device": dict,
    "enabled_by_default": bool,
    "entity_category": str,
    "icon": str,
    "json_attributes_template": str,
    "json_attributes_topic": str,
    "name": (str, type(None)),
    "object_id": str,
    "qos": int,
    "unique_id": str,
    "state_topic": str,
    "value_template": str,
    "expire_after": int,
    "force_update": bool,
    "encoding": str,
}
COMPONENTS: dict[str, dict[str, Any]] = {
    "binary_sensor": {
        "keys": {
            **COMMON,
            "device_class": str,
            "off_delay": int,
            "payload_on": str,
            "payload_off": str,
        },
        "required": {"state_topic"},
        # Binary sensor device classes (the ones this service uses are among them).
        "device_class": {"occupancy", "connectivity", "motion", "presence", "problem"},
    },
    "sensor": {
        "keys": {
            **COMMON,
            "device_class": (str, type(None)),
            "unit_of_measurement": str,
            "state_class": str,
            "suggested_display_precision": int,
            "last_reset_value_template": str,
            "options": list,
        },
        "required": {"state_topic"},
        "state_class": {"measurement", "total", "total_increasing", "measurement_angle"},
    },
}
DEVICE_KEYS: dict[str, type | tuple[type, ...]] = {
    "identifiers": (list, str),
    "connections": list,
    "name": str,
    "manufacturer": str,
    "model": str,
    "model_id": str,
    "sw_version": str,
    "hw_version": str,
    "suggested_area": str,
    "configuration_url": str,
    "via_device": str,
    "serial_number": str,
}


def problems(topic: str, config: dict[str, Any]) -> list[str]:
    """Return what is wrong with a discovery config (empty when Home Assistant takes it)."""
    out = []
    m = TOPIC.match(topic)
    if m is None:
        return [f"{topic}: not <prefix>/<component>/[<node_id>/]<object_id>/config"]
    spec = COMPONENTS.get(m["component"])
    if spec is None:
        return [f"{topic}: component {m['component']!r} not checked here"]
    for key, value in config.items():
        kind = spec["keys"].get(key)
        if kind is None:
            out.append(f"{topic}: unknown key {key!r}")
        elif not isinstance(value, kind):
            out.append(f"{topic}: {key} is {type(value).__name__}")
    for key in spec["required"] - set(config):
        out.append(f"{topic}: missing {key}")
    if "device_class" in config and "device_class" in spec:
        if config["device_class"] not in spec["device_class"]:
            out.append(f"{topic}: device_class {config['device_class']!r}")
    if "state_class" in config and config["state_class"] not in spec.get("state_class", ()):
        out.append(f"{topic}: state_class {config['state_class']!r}")
    device = config.get("device")
    if device is not None:
        if "unique_id" not in config:
            out.append(f"{topic}: a device needs the entity's unique_id")
        if not device.get("identifiers") and not device.get("connections"):
            out.append(f"{topic}: device needs identifiers or connections")
        for key, value in device.items():
            kind = DEVICE_KEYS.get(key)
            if kind is None or not isinstance(value, kind):
                out.append(f"{topic}: device key {key!r}")
    return out
