"""Model fingerprint and provenance records stored in every scene header (FORMAT.md, "Header")."""

from __future__ import annotations

import datetime
import os
import re
from dataclasses import dataclass
from typing import Any

from ..errors import LimitExceededError, MalformedHeaderError
from ..version import __version__
from .checks import exact_keys, require_map, require_sha256, require_shape, require_str
from .limits import MAX_TOKEN_DIM, MAX_TOKEN_VALUES, MAX_TOKENS

__all__ = ["ModelFingerprint", "Provenance", "PROVENANCE_KINDS"]

PROVENANCE_KINDS = ("encoded", "generated")
_PRINTABLE = re.compile(r"[^\x00-\x1f\x7f]+")
_UTC = re.compile(r"\d{4}-\d{2}-\d{2}T\d{2}:\d{2}:\d{2}(\.\d{1,9})?Z")


def _check_calendar(stamp: str) -> None:
    """``created_utc`` must name a real UTC instant (FORMAT.md "Text"): 2026-02-30 and 24:00 are out."""
    try:
        # the _UTC pattern has fixed the layout; the constructor checks the calendar (strptime did the same
        # at ~4x the cost of a verified load's header work)
        datetime.datetime(int(stamp[0:4]), int(stamp[5:7]), int(stamp[8:10]), int(stamp[11:13]), int(stamp[14:16]),
                          int(stamp[17:19]))
    except ValueError:
        raise MalformedHeaderError(f"provenance.created_utc {stamp!r:.44} is not a valid calendar date and "
                                   "time (ISO-8601 UTC, seconds 00-59)") from None
_DTYPE = re.compile(r"[a-z][a-z0-9_]{0,31}")
_FINGERPRINT_KEYS = {"model_id", "model_version", "config_sha256", "weights_sha256", "static_shape",
                     "dynamic_shape", "token_dtype"}
_PROVENANCE_KEYS = {"library_version", "created_utc", "source_capture_id", "kind"}


def _stamp() -> str:
    """The creation time to record: SOURCE_DATE_EPOCH where set, else now (UTC, whole seconds)."""
    fixed = os.environ.get("SOURCE_DATE_EPOCH", "")
    if not fixed:
        when = datetime.datetime.now(datetime.timezone.utc)
    else:
        if not (fixed.isascii() and fixed.isdigit()) or len(fixed) > 12:
            raise MalformedHeaderError(f"SOURCE_DATE_EPOCH must be whole seconds since 1970-01-01 UTC (digits "
                                       f"only), got {fixed!r:.40}; unset it to stamp the current time")
        try:
            when = datetime.datetime.fromtimestamp(int(fixed), datetime.timezone.utc)
        except (OverflowError, OSError, ValueError):
            raise MalformedHeaderError(f"SOURCE_DATE_EPOCH {fixed} is past the year 9999; unset it to stamp the "
                                       "current time") from None
    return when.strftime("%Y-%m-%dT%H:%M:%SZ")


def _shape(value: Any, what: str) -> tuple[int, int]:
    return require_shape(value, what, MAX_TOKENS, MAX_TOKEN_DIM, MAX_TOKEN_VALUES, LimitExceededError)


@dataclass(frozen=True)
class ModelFingerprint:
    """Identifies the model that produced a scene's tokens; the codec refuses any other model.

    Attributes:
        model_id: printable name of the model family (1..256 characters).
        model_version: printable version string (1..64 characters).
        config_sha256: SHA-256 (64 lowercase hex digits) of the model's canonical config.
        weights_sha256: SHA-256 of the weights file.
        static_shape: (N_s, d) of the static tokens Z_s the model produces.
        dynamic_shape: (N_d, d) of the dynamic tokens Z_d.
        token_dtype: the model's native token dtype name, e.g. "float32".
    """

    model_id: str
    model_version: str
    config_sha256: str
    weights_sha256: str
    static_shape: tuple[int, int]
    dynamic_shape: tuple[int, int]
    token_dtype: str = "float32"

    def __post_init__(self) -> None:
        require_str(self.model_id, "fingerprint.model_id", pattern=_PRINTABLE, hint="control characters")
        require_str(self.model_version, "fingerprint.model_version", max_chars=64, pattern=_PRINTABLE,
                    hint="control characters")
        require_sha256(self.config_sha256, "fingerprint.config_sha256")
        require_sha256(self.weights_sha256, "fingerprint.weights_sha256")
        object.__setattr__(self, "static_shape", _shape(self.static_shape, "fingerprint.static_shape"))
        object.__setattr__(self, "dynamic_shape", _shape(self.dynamic_shape, "fingerprint.dynamic_shape"))
        require_str(self.token_dtype, "fingerprint.token_dtype", max_chars=32, pattern=_DTYPE,
                    hint="a lowercase dtype name such as 'float32'")

    def matches(self, other: "ModelFingerprint") -> bool:
        """True when ``other`` names the same model: same id, version, config, weights, shapes, dtype."""
        return isinstance(other, ModelFingerprint) and self.to_dict() == other.to_dict()

    def short(self) -> str:
        """A printable one-line form for messages, e.g. ``vt4d-tiny@1.0 (cfg 1a2b3c4d, w 5e6f7a8b)``."""
        return (f"{self.model_id}@{self.model_version} (cfg {self.config_sha256[:8]}, "
                f"w {self.weights_sha256[:8]}, Z_s {self.static_shape[0]}x{self.static_shape[1]}, "
                f"Z_d {self.dynamic_shape[0]}x{self.dynamic_shape[1]})")

    def to_dict(self) -> dict[str, Any]:
        """The header form: a map of plain types (shapes as 2-element lists)."""
        return {
            "model_id": self.model_id, "model_version": self.model_version,
            "config_sha256": self.config_sha256, "weights_sha256": self.weights_sha256,
            "static_shape": list(self.static_shape), "dynamic_shape": list(self.dynamic_shape),
            "token_dtype": self.token_dtype,
        }

    @classmethod
    def from_dict(cls, data: Any, *, allow_extra: bool = False) -> "ModelFingerprint":
        """Parse the header form; raises MalformedHeaderError / LimitExceededError on any problem."""
        data = require_map(data, "fingerprint")
        exact_keys(data, _FINGERPRINT_KEYS, "fingerprint", allow_extra=allow_extra)
        return cls(**{k: data[k] for k in _FINGERPRINT_KEYS})


@dataclass(frozen=True)
class Provenance:
    """Where a scene came from.

    Attributes:
        library_version: vt4dcodec version that wrote the tokens.
        created_utc: ISO-8601 UTC time, ``YYYY-MM-DDTHH:MM:SS[.fraction]Z``.
        source_capture_id: the capture the tokens were encoded from, or None (e.g. generated scenes).
        kind: "encoded" (from a capture by the encoder) or "generated" (sampled from the prior).
    """

    library_version: str
    created_utc: str
    source_capture_id: str | None
    kind: str

    def __post_init__(self) -> None:
        require_str(self.library_version, "provenance.library_version", max_chars=64, pattern=_PRINTABLE,
                    hint="control characters")
        require_str(self.created_utc, "provenance.created_utc", max_chars=40, pattern=_UTC,
                    hint="expected ISO-8601 UTC like 2026-01-31T12:00:00Z")
        _check_calendar(self.created_utc)
        if self.source_capture_id is not None:
            require_str(self.source_capture_id, "provenance.source_capture_id", pattern=_PRINTABLE,
                        hint="control characters")
        if self.kind not in PROVENANCE_KINDS:
            raise MalformedHeaderError(f"provenance.kind must be one of {PROVENANCE_KINDS}, got {self.kind!r:.40}")

    @classmethod
    def now(cls, source_capture_id: str | None, kind: str = "encoded") -> "Provenance":
        """Provenance stamped with this library's version and the current UTC time (whole seconds), or the time
        ``SOURCE_DATE_EPOCH`` gives where it is set (reproducible-builds.org's convention: whole seconds since
        1970-01-01 UTC), so that the same input writes the same bytes."""
        return cls(__version__, _stamp(), source_capture_id, kind)

    def to_dict(self) -> dict[str, Any]:
        return {"library_version": self.library_version, "created_utc": self.created_utc,
                "source_capture_id": self.source_capture_id, "kind": self.kind}

    @classmethod
    def from_dict(cls, data: Any, *, allow_extra: bool = False) -> "Provenance":
        data = require_map(data, "provenance")
        exact_keys(data, _PROVENANCE_KEYS, "provenance", allow_extra=allow_extra)
        return cls(**{k: data[k] for k in _PROVENANCE_KEYS})
