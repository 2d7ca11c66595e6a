"""The library's version, recorded in every file it writes (``provenance.library_version``)."""

__version__ = "0.1.0"
