"""HTTP API service (FastAPI + uvicorn): skills, collectors, stats, health, evaluations.

Consumes: stats of every service, repertoire snapshots, liveliness tokens; forwards
``POST /skills/sample`` to the repertoire and ``POST /evaluate`` to the evaluator (Zenoh queries).
Produces: HTTP on ``--host``/``--port`` (OpenAPI at ``/docs``), stats (``api/stats``), a
liveliness token.
Run alone: ``python -m services.api --host 127.0.0.1 --port 8000 --bus.router tcp/127.0.0.1:7447``
(reads answer 503 until a repertoire snapshot arrives; ``GET /health`` always answers).
"""

from __future__ import annotations

from services.api.service import ApiArgs, ApiService
from services.common.cli import serve


def main() -> None:
    serve(ApiArgs, ApiService, "api", __doc__, signals=False)


if __name__ == "__main__":
    main()
