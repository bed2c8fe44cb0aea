"""The wire ring: message schema and bounds (schema), the messages, their codec, the Zenoh keys, and the
message of each sensor measurement (measurements)."""
