"""The tools ring: the command line, benchmarks, load test, demos, up/compose/secure, record/view.

Tools may import every ring below them (services, simulation, recordings, wire, cores); nothing below
imports a tool (tests/test_architecture.py)."""
