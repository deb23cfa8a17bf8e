"""LZF (liblzf) compression for PCL's ``DATA binary_compressed``, through liblzf's C code.

The C extension comes from the PyPI package ``python-neo-lzf`` (module ``lzf``; a
maintained fork of ``python-lzf`` with binary wheels for CPython 3.10-3.13), a core
dependency: it decompresses a 640x480 PCL cloud in about 10 ms, where the pure-Python
decoder this module used to carry took 0.35-0.5 s (``python scripts/bench_io.py``).

The stream format: a control byte below 32 starts a literal run of ``ctrl + 1`` bytes;
otherwise its top 3 bits give a back-reference length (7 = read one more length byte)
and the low 5 bits plus the next byte give the distance back.
"""

from __future__ import annotations

import lzf as _lzf

__all__ = ["lzf_decompress", "lzf_compress"]


def lzf_decompress(data, out_len: int) -> bytes:
    """Decompress an LZF stream whose decompressed size is known.

    Parameters
    ----------
    data : bytes-like
        The compressed stream.
    out_len : int
        The expected decompressed size in bytes.

    Returns
    -------
    bytes
        Exactly ``out_len`` bytes.

    Raises
    ------
    ValueError
        If the stream is corrupt or truncated, or decompresses to a size other
        than ``out_len``.

    Examples
    --------
    >>> lzf_decompress(bytes([2]) + b"abc" + bytes([0x20, 2]), 6)
    b'abcabc'
    """
    if out_len < 0:
        raise ValueError(f"out_len must be >= 0; got {out_len}")
    data = bytes(data)
    if not data:
        out = b""
    else:
        try:
            # liblzf gives None when the output would exceed the bound: ask for one
            # byte more than declared so that "too long" is told apart from "exact".
            out = _lzf.decompress(data, out_len + 1)
        except ValueError as err:
            raise ValueError(f"LZF stream is corrupt or truncated ({err})") from None
        if out is None:
            raise ValueError(f"LZF stream decompresses to more than the declared {out_len} bytes")
    if len(out) != out_len:
        raise ValueError(f"LZF stream decompresses to {len(out)} bytes but {out_len} were declared")
    return out


def lzf_compress(data) -> bytes:
    """Compress with liblzf; the output is what PCL writes and reads.

    Incompressible input is stored as literal runs (one control byte per 32 bytes).

    Examples
    --------
    >>> payload = b"abcabcabcabc" * 10
    >>> lzf_decompress(lzf_compress(payload), len(payload)) == payload
    True
    """
    data = bytes(data)
    if not data:
        return b""
    # The worst case of LZF is one control byte per 32 literals; liblzf returns None
    # when the output does not fit the bound, which this bound rules out.
    packed = _lzf.compress(data, len(data) + len(data) // 32 + 16)
    if packed is None:
        raise ValueError(f"liblzf could not compress {len(data)} bytes within the worst-case bound")
    return packed
