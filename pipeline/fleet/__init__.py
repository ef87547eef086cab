"""The fleet: the per-unit pipeline over many campaigns on Dask (``engine``) and its report."""
