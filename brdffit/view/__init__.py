"""Looking at tables and fits: sphere renders (:mod:`.render`, JAX) and the
figures built on them (:mod:`.plots`, matplotlib, the ``plots`` extra)."""
