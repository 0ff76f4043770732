"""Fit jobs: what a request means and costs, and its creation.

The meaning is the library's (``brdffit.request.FitRequest``): a request the
library would refuse is refused here, before anything is queued, with the
library's own words. The cost policy (``api.estimate`` against the server's
limits) lives here too, so that every handler and the page say the same. A job's
result among its fits is the library's one rule (``brdffit.selection.chosen_result``).
"""

from __future__ import annotations

import sqlite3
from dataclasses import dataclass

from api.estimate import RECENT_JOBS, Estimate, estimate, machine_factor
from api.settings import Settings
from api.store import JobRecord, Store
from brdffit.errors import FitInputError
from brdffit.request import FitRequest


class TableNotFound(LookupError):
    """The request names a table the store does not hold."""


class OverLimits(ValueError):
    """The request's estimated cost is over the server's limits; the message says
    by how much and what to ask for instead."""


def over_limits(cost: Estimate, settings: Settings) -> str | None:
    """Why ``cost`` is over the server's limits, or None."""
    over = []
    if cost.memory_mib > settings.max_job_memory_mib:
        over.append(f"memory {cost.memory_mib:,.0f} MiB > {settings.max_job_memory_mib:,} MiB "
                    "(BRDFFIT_MAX_JOB_MEMORY_MIB)")
    if cost.seconds > settings.max_job_estimate_s:
        over.append(f"time {cost.seconds:,.0f} s > {settings.max_job_estimate_s:,.0f} s "
                    "(BRDFFIT_MAX_JOB_ESTIMATE_S)")
    if not over:
        return None
    return (f"this fit is estimated over the server's limits: {'; '.join(over)}; estimate "
            f"for {cost.detail}. Ask for fewer samples or starts.")


def measured_machine(store: Store) -> float:
    """How much slower than the estimate's constants this server's workers ran its
    recent jobs (``api.estimate.machine_factor``; 1 with none measured)."""
    measured = []
    for request, bins, run_s in store.recent_runs(RECENT_JOBS):
        try:
            fitted = FitRequest.from_dict(request)
        except FitInputError:  # stored by another version, whose models this one lacks
            continue
        measured.append((estimate(fitted, bins).reference_seconds, run_s))
    return machine_factor(measured)


@dataclass(frozen=True)
class Costed:
    """A request checked against its table, and what it would cost there."""

    request: FitRequest
    cost: Estimate
    #: how much slower than the constants' machine this server's recent jobs ran (1: none
    #: slower, or none measured): ``cost.seconds`` holds it
    machine: float
    #: why the cost is over the server's limits (:func:`over_limits`), or None
    over: str | None


def costed(store: Store, settings: Settings, table_id: str, request: dict) -> Costed:
    """``request`` (``FitRequest.to_dict()``'s form) checked by the library against the
    table ``table_id``, and its cost estimate against the server's limits: what
    :func:`create` decides by, and what ``POST /v1/fits/estimate`` answers before
    anything is queued. Raises ``TableNotFound`` and ``FitInputError``."""
    table = store.get_table(table_id)
    if table is None:
        raise TableNotFound(f"no table {table_id}; upload it with POST /v1/tables")
    request = FitRequest.from_dict(request)
    if request.options.physical and table.summary.get("input") is not None:
        # known now, as the fit would find it: the job was accepted, then failed
        raise FitInputError(f"table {table_id} is a sample list: the physical bounds are not "
                            "available for a sample list yet (their albedo check reads a "
                            "table); fit it without them")
    machine = measured_machine(store)
    cost = estimate(request, table.summary["measured_bins"], machine=machine)
    return Costed(request, cost, machine, over_limits(cost, settings))


def create(store: Store, settings: Settings, table_id: str, request: dict) -> JobRecord:
    """Queue a fit job of ``request`` (``FitRequest.to_dict()``'s form): checked by the
    library, its cost against the limits (:func:`costed`), then stored in the library's
    own form. Raises ``TableNotFound``, ``FitInputError``, ``OverLimits``."""
    checked = costed(store, settings, table_id, request)
    request = checked.request
    if (why := checked.over) is not None:
        # Refused before anything is queued or allocated: say by how much, and why.
        raise OverLimits(why)
    try:
        return store.create_job(table_id, request.to_dict())
    except sqlite3.IntegrityError:
        # the table's foreign key: it was deleted while the request was checked (a 503,
        # "storage failed, try again later", which no retry could mend)
        raise TableNotFound(f"no table {table_id}: it was deleted while this fit was being "
                            "checked") from None
