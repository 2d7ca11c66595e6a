"""The single-scene ``.vt4d`` container (numpy, msgpack and zstandard only; never torch or cv2).

Specification: FORMAT.md, Part I.  Typical use::

    from vt4dcodec.format import Scene, ModelFingerprint, save, load, open_scene
    save(scene, "clip.vt4d")                 # int8 tokens by default
    save(scene, "small.vt4d", encoding="int6-rans")   # entropy-coded tokens (format 1.1)
    f = open_scene("clip.vt4d")              # lazy: header and table only
    f.fingerprint, f.static_tokens()         # sections decoded on access
    save(scene, "rd.vt4d", encoding="learned-rans", quality=3)   # the model's entropy tables (format 1.6)
"""

from .encodings import ALL_ENCODINGS, ENCODINGS, LEARNED_ENCODING, RANS_ENCODINGS, max_abs_error
from .learned import EntropyTables, set_tables_resolver
from .fingerprint import PROVENANCE_KINDS, ModelFingerprint, Provenance
from .layout import FORMAT_MAJOR, FORMAT_MINOR, SCENE_MAGIC
from .reader import SceneFile, load, loads, open_scene, verify
from .scene import Scene
from .writer import DEFAULT_COMPRESSION_LEVEL, dumps, save

__all__ = ["Scene", "ModelFingerprint", "Provenance", "SceneFile", "save", "load", "dumps", "loads", "open_scene",
           "verify", "ENCODINGS", "RANS_ENCODINGS", "SCENE_MAGIC", "FORMAT_MAJOR", "FORMAT_MINOR", "PROVENANCE_KINDS",
           "DEFAULT_COMPRESSION_LEVEL", "max_abs_error", "LEARNED_ENCODING", "ALL_ENCODINGS", "EntropyTables", "set_tables_resolver"]
