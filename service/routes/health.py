"""``/healthz`` (the process answers) and ``/readyz`` (model loaded, a job would be admitted); never need a key."""

from __future__ import annotations

from fastapi import APIRouter
from fastapi.responses import JSONResponse

from ..deps import ManagerDep
from ..schemas import Health, QueueState, Readiness, WorkerState

router = APIRouter(tags=["health"])


@router.get("/healthz", summary="Liveness: the process is up", response_model=Health)
async def healthz() -> Health:
    return Health()


@router.get(
    "/readyz",
    summary="Readiness: the model is loaded and a job would be accepted",
    response_model=Readiness,
    responses={
        503: {
            "model": Readiness,
            "description": "Loading the model, model failed, or all workers and the queue are full.",
        }
    },
)
async def readyz(manager: ManagerDep) -> JSONResponse:
    ready, status, message = manager.readiness()
    waiting, running, admitted = manager.queue_state()
    s = manager.settings
    body = Readiness(
        ready=ready,
        status=status,
        message=message,
        model=manager.model_info,
        workers=WorkerState(total=s.workers, busy=min(running, s.workers)),
        queue=QueueState(depth=waiting, capacity=s.capacity, admitted=admitted, uploads=manager.uploads_in_flight()),
    )
    return JSONResponse(body.model_dump(mode="json"), status_code=200 if ready else 503)
