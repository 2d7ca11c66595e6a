"""The single-scene .vt4d container (numpy, msgpack and zstandard only; never torch)."""
