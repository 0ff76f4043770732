"""The batch job: many tables x models into one resumable HDF5 file.

- :mod:`.job`: ``run_batch``, the loop that schedules fits and stores them;
- :mod:`.tasks`: one table's fits, as a worker runs them;
- :mod:`.cluster`: where the fits run (in process, or on a Dask cluster);
- :mod:`.store`: the HDF5 results file;
- :mod:`.progress`: the progress line;
- :mod:`.report`: ranking the models of a results file.

Needs the ``batch`` extra (h5py, Dask) for :mod:`.job` and :mod:`.cluster`.
"""
