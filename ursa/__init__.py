"""URSA core: the algorithm and the simulation. Imports no zenoh, FastAPI or viser."""
