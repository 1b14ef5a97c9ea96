"""Decoded frame batches -> every node's NMT state timeline: decode, the event tables, the
compaction of long steady runs, gaps, the model and the build (`build.py`)."""
