"""Type hints of the compiled rANS coder (_rans_native.c); rans.py says what each function does."""

import numpy as np

# what the C code reads and writes through the buffer protocol (numpy arrays contiguous, of the dtype named)
_Buffer = bytes | bytearray | memoryview | np.ndarray

# decode / decode_mapped return (symbols decoded, stream position, final state of each lane, [bad code]); a
# stream of K lanes (format 1.5; 1 when not given) starts with its K states
def decode(stream: _Buffer, freqs_u32: _Buffer, out_u16: _Buffer, lanes: int = 1, /) -> tuple[int, int, tuple[int, ...]]: ...
def decode_mapped(
    jobs: tuple[tuple[_Buffer, _Buffer, _Buffer, int, _Buffer, _Buffer, _Buffer, int, int], ...], /
) -> list[tuple[int, int, tuple[int, ...], int]]: ...
def encode(jobs: tuple[tuple[_Buffer, _Buffer, int], ...], /) -> list[bytes | None]: ...
def column_histograms(codes_u8: _Buffer, cols: int, size: int, out_i64: _Buffer, /) -> None: ...
# context-coded single chains (format 1.6): symbol k with table ctx_u16[k] of the T x A freqs_u32
def encode_ctx(symbols_u16: _Buffer, ctx_u16: _Buffer, freqs_u32: _Buffer, alphabet: int, /) -> bytes | None: ...
def decode_ctx(stream: _Buffer, ctx_u16: _Buffer, freqs_u32: _Buffer, alphabet: int, out_u16: _Buffer,
               dep_i32: _Buffer = ..., centre_u16: _Buffer = ..., dep2_i32: _Buffer = ..., centre2_u16: _Buffer = ...,
               offsets_i32: _Buffer = ...,
               /) -> tuple[int, int, int]: ...
