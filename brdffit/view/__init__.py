"""Looking at tables and fits: the figures (:mod:`.plots`: matplotlib, the ``plots``
extra, and the sphere renders of ``brdffit.fitting.sphere``, JAX), and their names
and options (:mod:`.kinds`, neither), which the service's front reads."""
