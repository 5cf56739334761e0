"""The service's links to the home's other systems over MQTT (spec 09), one module per part:

* `mqtt`: one MQTT connection kept up in its own thread (`MqttLink`), the broker's URL
  (`BrokerUrl`, its password a secret), the messages it hands on (`Message`).
* `home`: what the home hears (`HomePublisher`): zones' occupancy, events, targets and cameras'
  health, with Home Assistant's MQTT discovery.
* `frigate`: Frigate as a source (`FrigateSource`): its person boxes become detections fed to
  the space's tracker.

Nothing is imported here: the settings read `mqtt` alone, without the tracker `frigate` feeds.
"""
