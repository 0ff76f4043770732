"""What the service does, below its HTTP handlers: fits (``fits``) and tables (``tables``).

A handler in ``api/routes/`` parses the request, calls one function here and maps
its errors to HTTP statuses; the decisions (what a request means, what it costs,
which fit is the result, how a table is validated and stored) are made here once,
on top of the library (``brdffit.request``, ``brdffit.io.merl``).
"""
