"""Run files: the HDF5 run format, MATLAB import, videos of a run."""
