"""The schemathesis harness of the API tests (``test_api.py``, ``test_adapt_api.py``): the app's
OpenAPI schema, the hypothesis settings of a run, and our checks on top of schemathesis' own
(never a 500, a reason with every 422).

A test module states its app and the routes it covers, then::

    SCHEMA = openapi_schema(app, path_regex="^/adapt")

    @SCHEMA.parametrize()
    @SETTINGS
    def test_openapi_property_based_...(case: Any) -> None:
        call_and_validate(case)

schemathesis is a pinned dev dependency, imported at the top: a missing package or an entry
point renamed by an upgrade fails the importing test module loudly, never turns into a skip.
"""

from __future__ import annotations

from typing import Any

import schemathesis
from hypothesis import HealthCheck, settings

SETTINGS = settings(
    max_examples=40, deadline=None, derandomize=True, suppress_health_check=list(HealthCheck)
)
"""40 examples per operation, derandomized (the same cases on every run), no deadline."""


def openapi_schema(app: Any, path_regex: str | None = None) -> schemathesis.BaseSchema:
    """The app's ``/openapi.json``, read in process (ASGI); only the operations whose path
    matches ``path_regex`` when one is given."""
    schema = schemathesis.openapi.from_asgi("/openapi.json", app)
    return schema if path_regex is None else schema.include(path_regex=path_regex)


def no_500(ctx: Any, response: Any, case: Any) -> bool:
    """Never a 500 (a 503 only where the spec documents it: a missing peer)."""
    assert response.status_code != 500, f"500 on {case.method} {case.path}: {response.text}"
    return True


def a_reason_with_every_422(ctx: Any, response: Any, case: Any) -> bool:
    """Every 422 says where and why, in FastAPI's validation-error shape."""
    if response.status_code == 422:
        detail = response.json()["detail"]
        assert isinstance(detail, list) and detail, response.text
        assert all(e.get("loc") and e.get("msg") for e in detail), response.text
    return True


def call_and_validate(case: Any) -> None:
    """Call the app with ``case`` and run every schemathesis check ("schema-valid data is
    accepted" included) and ours."""
    case.call_and_validate(additional_checks=[no_500, a_reason_with_every_422])
