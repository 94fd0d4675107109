"""A production lot: every unit identified as `analysis fit` does, on Dask, and judged
against the others (`docs/lot.md`)."""
