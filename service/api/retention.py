"""Retention routes: ``GET``/``PUT /api/retention`` (the policy of
``fpscan.service.jobs.lifecycle``, stored in the job database so a restart keeps it)."""
from __future__ import annotations

from fastapi import APIRouter, Depends, HTTPException

from fpscan.service.api.context import Context, ctx, read_access, require_token
from fpscan.service.api.models import Retention
from fpscan.service.jobs import lifecycle

__all__ = ["router", "get_retention", "put_retention"]

router = APIRouter(prefix="/api/retention", tags=["storage"])


@router.get("", response_model=Retention, dependencies=[Depends(read_access)])
def get_retention(context: Context = Depends(ctx)) -> Retention:
    """The retention policy in force (the stored one, else the service settings')."""
    return Retention(**lifecycle.get_retention(context.store, context.settings))


@router.put("", response_model=Retention, dependencies=[Depends(require_token)])
def put_retention(body: Retention, context: Context = Depends(ctx)) -> Retention:
    """Set the retention policy and apply it at once; it stays in force across
    restarts."""
    try:
        policy = lifecycle.set_retention(context.store, body.model_dump())
    except ValueError as exc:
        raise HTTPException(422, str(exc)) from None
    lifecycle.apply_retention(context.store, context.settings)
    return Retention(**policy)
