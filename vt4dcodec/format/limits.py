"""Documented limits of the v1 scene container (FORMAT.md, "Limits").

Every size a file declares is checked against these constants *and* against the real data length
before anything is allocated, so a hostile header cannot make a reader allocate what it claims.
"""

from __future__ import annotations

__all__ = [
    "PREAMBLE_SIZE", "SECTION_ENTRY_SIZE", "SECTION_ALIGNMENT",
    "MAX_HEADER_BYTES", "MAX_HEADER_DEPTH", "MAX_METADATA_BYTES", "MAX_METADATA_DEPTH",
    "MAX_STRING_CHARS", "MAX_CONTAINER_ITEMS", "MAX_SECTIONS", "MAX_TOKENS", "MAX_TOKEN_DIM",
    "MAX_TOKEN_VALUES", "MAX_FRAMES", "MAX_IMAGE_SIDE", "MAX_SECTION_RAW_BYTES", "MAX_EXTRA_CAMERAS",
]

PREAMBLE_SIZE = 64            # bytes, fixed in v1
SECTION_ENTRY_SIZE = 40       # bytes per section-table entry
SECTION_ALIGNMENT = 64        # every section payload starts at a multiple of this (container-relative)

MAX_HEADER_BYTES = 1 << 20    # 1 MiB of msgpack header
MAX_HEADER_DEPTH = 16         # nesting of maps/arrays in the header, the top-level map counting as 1
MAX_METADATA_BYTES = 256 << 10  # 256 KiB: the user metadata map, msgpack-encoded
MAX_METADATA_DEPTH = 8        # nesting inside the user metadata map (the map itself counts as 1)
MAX_STRING_CHARS = 65536      # any single string in the header (UTF-8 bytes)
MAX_CONTAINER_ITEMS = 65536   # elements of any single header array or map
MAX_SECTIONS = 64             # entries in the section table

MAX_TOKENS = 1 << 20          # N_s and N_d each
MAX_TOKEN_DIM = 4096          # d
MAX_TOKEN_VALUES = 1 << 26    # N * d for one token section (256 MiB as float32)
MAX_FRAMES = 1 << 16          # T, poses in the cameras section
MAX_IMAGE_SIDE = 1 << 16      # width and height in pixels
MAX_EXTRA_CAMERAS = 63        # trajectories in the extra cameras section (format 1.4): 64 encoded cameras in all
MAX_SECTION_RAW_BYTES = 1 << 30  # any section's decompressed size
