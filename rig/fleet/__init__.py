"""Work on many recordings at once: in local worker processes or on a Dask cluster."""
