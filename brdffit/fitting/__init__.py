"""Fitting one model to one table.

- :mod:`.options`: the fit contract (``FitOptions``), its defaults declared once;
- :mod:`.sampling`: which bins a fit looks at, and their weights;
- :mod:`.loss`: the residuals a fit minimises, and the errors it reports;
- :mod:`.starts`: data-driven starting points;
- :mod:`.solver`: the Levenberg-Marquardt solver and its stop rule;
- :mod:`.pipeline`: ``fit()``, which ties them together;
- :mod:`.scene`: weighting a fit towards the directions a scene uses;
- :mod:`.result`: ``FitResult`` (NumPy only, so a client can read one without JAX).

Importing this package imports none of them.
"""
