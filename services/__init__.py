"""capataz services: thin processes that parse settings, open a Zenoh session and wire cores to keys."""
