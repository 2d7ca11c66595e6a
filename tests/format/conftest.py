"""The format tests read the learned-rans vectors (format 1.6) with the test model's entropy tables, found by
fingerprint as an installed model's tables are (spec/make_vectors.py ``install_spec_tables``)."""

from format_strategies import load_vector_tool

load_vector_tool().install_spec_tables()
