"""The brdffit fitting service: a REST API over the library (``brdffit serve``).

- ``main``: builds the FastAPI app (routers, error handlers, the job queue's life);
- ``settings``: every knob, from ``BRDFFIT_*`` environment variables;
- ``deps``: what routes receive (settings, store, queue) and the bearer-token check;
- ``store``: uploaded tables (content-addressed files) and fit jobs (SQLite), the
  database check at start;
- ``jobs``: the queue that runs fit jobs off the event loop, survives restarts and
  storage errors;
- ``runner``: where library calls execute (worker processes; a Dask cluster later);
- ``tasks``: the library calls that run inside a worker;
- ``estimate``: a requested fit's memory and time, checked before it is queued;
- ``limits``: request body size and read-timeout bounds, JSON 500s;
- ``repair``: ``python -m api.repair check|backup|rebuild``;
- ``routes``: one module per resource, each with its schemas;
- ``static/swagger-ui``: the files ``/docs`` loads (vendored, Apache-2.0).
"""

from brdffit import extras

extras.require("service", "the brdffit service (the api package)")
