"""The runtime every service shares: Zenoh sessions from settings, hand-off primitives, the service base,
the scatter round over members, and CLI helpers. The one place (with the services) that talks to Zenoh."""
