"""The wire ring: message schema and bounds (schema), the messages, their codec and the Zenoh keys."""
