"""Measured tables: the MERL ``.binary`` format (:mod:`.merl`), its bin layout over
half/difference angles (:mod:`.angles`) and the directions at the bin centres
(:mod:`.grid`). NumPy only: reading a table never imports JAX."""
