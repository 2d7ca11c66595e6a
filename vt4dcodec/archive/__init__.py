"""Multi-scene archives: records, index, footer, recovery, fsspec access."""
