"""Batch re-processing of recording archives on Dask (tofd batch) and golden replay checks."""
