"""The integration tests' shared fixtures: the compose image, built once per session for
``test_compose.py`` and ``test_compose_faults.py``."""

from tests.integration.compose import image

__all__ = ["image"]
