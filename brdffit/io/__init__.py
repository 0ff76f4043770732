"""Measured reflectance: the MERL ``.binary`` format (:mod:`.merl`), its bin layout over
half/difference angles (:mod:`.angles`) and the directions at the bin centres
(:mod:`.grid`); samples at any direction pairs (:mod:`.measurements`) and the readers
of every layout, MERL, ASTM E1392, CSV, HDF5, MATLAB, .npz (:mod:`.readers`). NumPy (and h5py) only:
reading a table never imports JAX."""
