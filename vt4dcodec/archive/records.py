"""Bridge between archive records and the single-scene container (``vt4dcodec.format``).

A record payload is a complete ``.vt4d`` byte string.  The archive core treats it as opaque bytes
plus a summary dict; this module turns a Scene (or ``.vt4d`` bytes) into that pair and back.
"""

from __future__ import annotations

from typing import Any

from ..errors import ArchiveError
from ..format import Scene, dumps, open_scene, verify
from ..format.sections import DEFAULT_MAX_DECODED_BYTES

__all__ = ["record_from", "summarize_payload", "verify_payload", "SUMMARY_FIELDS"]


def _jsonable(value: Any) -> Any:
    """Reduce a summary to msgpack/JSON-safe types (tuples -> lists, numpy scalars -> Python)."""
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if hasattr(value, "item") and callable(value.item):
        return value.item()
    return value


#: the SceneFile.summary() fields an index keeps (the section table stays in the record)
SUMMARY_FIELDS = ("bytes", "frames", "width", "height", "static_shape", "dynamic_shape", "encoding",
                  "fingerprint", "source_capture_id", "kind", "created_utc")


def summarize_payload(payload: bytes) -> dict[str, Any]:
    """The index summary of a ``.vt4d`` payload: :data:`SUMMARY_FIELDS` of ``SceneFile.summary()``."""
    full = open_scene(payload).summary()
    summary = {k: _jsonable(full[k]) for k in SUMMARY_FIELDS if k in full}
    summary["bytes"] = len(payload)
    return summary


def verify_payload(payload: bytes, *, max_decoded_bytes: int | None = DEFAULT_MAX_DECODED_BYTES) -> None:
    """Full container validation of one record (raises a FormatError subclass; LimitExceededError for a
    scene that decodes to more than ``max_decoded_bytes``, FORMAT.md I.7)."""
    verify(payload, max_decoded_bytes=max_decoded_bytes)


def record_from(obj: Any, *, validate: bool = True,
                max_decoded_bytes: int | None = DEFAULT_MAX_DECODED_BYTES) -> bytes:
    """``.vt4d`` bytes for a Scene or for bytes/bytearray/memoryview already in the container format.

    With ``validate`` the bytes are fully verified by the container (so nothing invalid is archived), within
    the decoded-size budget ``max_decoded_bytes``.
    """
    if isinstance(obj, (bytes, bytearray, memoryview)):
        payload = bytes(obj)
        if validate:
            verify_payload(payload, max_decoded_bytes=max_decoded_bytes)
        return payload
    if isinstance(obj, Scene):
        return dumps(obj)
    raise ArchiveError(f"cannot archive a {type(obj).__name__}: pass a Scene or .vt4d bytes")
