"""Fleet scale: many logs from any fsspec URL, checked on an executor, into a Parquet dataset."""
