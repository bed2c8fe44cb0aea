"""capataz pure cores: arrays in, value objects out. No Zenoh, no files, no global state."""
