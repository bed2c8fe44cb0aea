"""The recordings ring: capataz MCAP recordings of wire messages (above the wire ring)."""
