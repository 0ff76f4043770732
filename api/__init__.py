"""The brdffit fitting service: a REST API over the library (``brdffit serve``).

- ``main``: builds the FastAPI app (routers, error handlers, the job queue's life);
- ``settings``: every knob, from ``BRDFFIT_*`` environment variables;
- ``deps``: what routes receive (settings, store, queue) and the bearer-token check;
- ``store``: uploaded tables (content-addressed files) and fit jobs (SQLite);
- ``jobs``: the queue that runs fit jobs off the event loop and survives restarts;
- ``runner``: where library calls execute (worker processes; a Dask cluster later);
- ``tasks``: the library calls that run inside a worker;
- ``routes``: one module per resource, each with its schemas.
"""

from brdffit import extras

extras.require("service", "the brdffit service (the api package)")
