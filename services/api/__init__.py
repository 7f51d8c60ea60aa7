"""HTTP API of a live URSA run (FastAPI): skills, collectors, stats, health, evaluations."""
