"""LZF (liblzf) decompression and a simple compressor, in pure Python.

PCL's ``DATA binary_compressed`` stores its payload with LZF. The format is a
sequence of tokens: a control byte below 32 starts a literal run of ``ctrl + 1``
bytes; otherwise its top 3 bits give a back-reference length (7 = read one more
length byte) and the low 5 bits plus the next byte give the distance back.

When the C extension of the PyPI package ``python-lzf`` (module ``lzf``) is
installed it does the work (a 640x480 PCL cloud in a few tens of milliseconds);
otherwise the pure-Python code below does, looping over tokens rather than bytes,
in a few tenths of a second (``python scripts/bench_io.py`` prints both).
"""

from __future__ import annotations

import functools

__all__ = ["lzf_decompress", "lzf_compress", "have_c_lzf"]

_BACKENDS = ("auto", "c", "python")

_MAX_LITERAL = 32
_MAX_OFFSET = 1 << 13
_MAX_REF = 264  # 7 + 255 + 2


@functools.lru_cache(maxsize=1)
def _c_module():
    try:
        import lzf
    except ImportError:
        return None
    return lzf if hasattr(lzf, "decompress") and hasattr(lzf, "compress") else None


def have_c_lzf() -> bool:
    """True when the C extension from ``python-lzf`` is importable."""
    return _c_module() is not None


def _pick(backend: str):
    if backend not in _BACKENDS:
        raise ValueError(f"backend must be one of {_BACKENDS}; got {backend!r}")
    module = _c_module() if backend in ("auto", "c") else None
    if backend == "c" and module is None:
        raise ValueError("backend 'c' needs the python-lzf package (module lzf), which is not installed")
    return module


def lzf_decompress(data, out_len: int, *, backend: str = "auto") -> bytes:
    """Decompress an LZF stream whose decompressed size is known.

    Parameters
    ----------
    data : bytes-like
        The compressed stream.
    out_len : int
        The expected decompressed size in bytes.
    backend : {"auto", "c", "python"}
        ``auto`` uses python-lzf's C code when installed, else pure Python.

    Returns
    -------
    bytes
        Exactly ``out_len`` bytes.

    Raises
    ------
    ValueError
        If the stream is truncated, refers back before its start, or decompresses
        to a size other than ``out_len``.

    Examples
    --------
    >>> lzf_decompress(bytes([2]) + b"abc" + bytes([0x20, 2]), 6)
    b'abcabc'
    """
    data = bytes(data)
    if out_len < 0:
        raise ValueError(f"out_len must be >= 0; got {out_len}")
    module = _pick(backend)
    if module is not None:
        return _decompress_c(module, data, out_len)
    return _decompress_python(data, out_len)


def _decompress_c(module, data: bytes, out_len: int) -> bytes:
    if not data:
        out = b""
    else:
        try:
            # python-lzf returns None when the output would exceed out_len + 1 bytes.
            out = module.decompress(data, out_len + 1)
        except ValueError as err:
            raise ValueError(f"LZF stream is corrupt or truncated ({err})") from None
        if out is None:
            raise ValueError(f"LZF stream decompresses to more than the declared {out_len} bytes")
    if len(out) != out_len:
        raise ValueError(f"LZF stream decompresses to {len(out)} bytes but {out_len} were declared")
    return bytes(out)


def _decompress_python(data: bytes, out_len: int) -> bytes:
    out = bytearray(out_len)
    ip = op = 0
    n = len(data)
    # One iteration per token, back-references first (the commonest token in PCL
    # files). Bounds are checked once at the end: a slice assignment past the end
    # grows `out`, a short literal slice leaves ip > n, a cut back-reference raises
    # IndexError.
    try:
        while ip < n:
            ctrl = data[ip]
            if ctrl >= 32:
                length = ctrl >> 5
                if length == 7:
                    length = 9 + data[ip + 1]
                    ref = op - ((ctrl & 0x1F) << 8) - data[ip + 2] - 1
                    ip += 3
                else:
                    length += 2
                    ref = op - ((ctrl & 0x1F) << 8) - data[ip + 1] - 1
                    ip += 2
                if ref < 0:
                    raise ValueError(
                        f"LZF back-reference points {-ref} bytes before the start of the output"
                    )
                end = op + length
                if op - ref >= length:
                    out[op:end] = out[ref:ref + length]
                else:
                    # Overlapping copy repeats the last op - ref bytes (run-length encoding).
                    out[op:end] = (out[ref:op] * (length // (op - ref) + 1))[:length]
                op = end
            else:
                ip += 1
                end = ip + ctrl + 1
                out[op:op + ctrl + 1] = data[ip:end]
                op += ctrl + 1
                ip = end
    except IndexError:
        raise ValueError(f"LZF stream truncated inside a back-reference at offset {ip}") from None
    if ip > n:
        raise ValueError(f"LZF stream truncated: the last literal run needs {ip - n} more bytes")
    if op != out_len or len(out) != out_len:
        raise ValueError(f"LZF stream decompresses to {op} bytes but {out_len} were declared")
    return bytes(out)


def lzf_compress(data, *, backend: str = "auto") -> bytes:
    """Compress with LZF; output readable by liblzf and PCL.

    With python-lzf installed this is liblzf's C code. The pure-Python fallback
    (greedy, 3-byte hash table) takes about a microsecond per input byte: fine
    for small payloads and test files, seconds for a VGA cloud.

    Parameters
    ----------
    data : bytes-like
    backend : {"auto", "c", "python"}

    Returns
    -------
    bytes

    Examples
    --------
    >>> payload = b"abcabcabcabc" * 10
    >>> lzf_decompress(lzf_compress(payload), len(payload)) == payload
    True
    """
    data = bytes(data)
    module = _pick(backend)
    if module is not None and data:
        # Worst case of LZF is one control byte per 32 literals; python-lzf gives
        # None when the output does not fit the bound.
        packed = module.compress(data, len(data) + len(data) // 32 + 16)
        if packed is not None:
            return packed
    return _compress_python(data)


def _compress_python(data: bytes) -> bytes:
    n = len(data)
    out = bytearray()
    table: dict[bytes, int] = {}
    literal_start = 0
    i = 0

    def flush_literals(end: int) -> None:
        start = literal_start
        while start < end:
            run = min(_MAX_LITERAL, end - start)
            out.append(run - 1)
            out.extend(data[start:start + run])
            start += run

    while i + 2 < n:
        key = data[i:i + 3]
        ref = table.get(key)
        table[key] = i
        if ref is not None and 0 < i - ref <= _MAX_OFFSET:
            length = 3
            limit = min(_MAX_REF, n - i)
            while length < limit and data[ref + length] == data[i + length]:
                length += 1
            flush_literals(i)
            offset = i - ref - 1
            code = length - 2
            if code < 7:
                out.append((code << 5) | (offset >> 8))
            else:
                out.append((7 << 5) | (offset >> 8))
                out.append(code - 7)
            out.append(offset & 0xFF)
            i += length
            literal_start = i
        else:
            i += 1
    flush_literals(n)
    return bytes(out)
