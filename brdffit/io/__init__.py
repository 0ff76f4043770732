"""Measured reflectance: the MERL ``.binary`` format (:mod:`.merl`), its bin layout over
half/difference angles (:mod:`.angles`) and the directions at the bin centres
(:mod:`.grid`); samples at any direction pairs (:mod:`.measurements`) and the readers
of every layout (:mod:`.readers`, which chooses one by a file's suffix or content):
ASTM E1392, CSV and Excel (:mod:`.text_samples`, :mod:`.workbook`), HDF5, MATLAB and .npz
(:mod:`.named_arrays`), in one vocabulary of column names (:mod:`.columns`). NumPy
(and h5py, scipy for MATLAB) only: reading a table never imports JAX."""
