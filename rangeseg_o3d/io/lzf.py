"""LZF (liblzf) decompression and a simple compressor, in pure Python.

PCL's ``DATA binary_compressed`` stores its payload with LZF. The format is a
sequence of tokens: a control byte below 32 starts a literal run of ``ctrl + 1``
bytes; otherwise its top 3 bits give a back-reference length (7 = read one more
length byte) and the low 5 bits plus the next byte give the distance back.

Decompression loops over tokens, not bytes: copies are slice assignments, so a
640x480 PCL cloud (4.9 MB out) takes a few tenths of a second
(``python scripts/bench_io.py`` prints the figure).
"""

from __future__ import annotations

__all__ = ["lzf_decompress", "lzf_compress"]

_MAX_LITERAL = 32
_MAX_OFFSET = 1 << 13
_MAX_REF = 264  # 7 + 255 + 2


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
    out = bytearray(out_len)
    ip = op = 0
    n = len(data)
    # One iteration per token; the body is kept flat because it is the hot loop.
    while ip < n:
        ctrl = data[ip]
        if ctrl < 32:
            ip += 1
            end = ip + ctrl + 1
            if end > n:
                raise ValueError(
                    f"LZF stream truncated: literal run needs {end - n} more bytes at offset {ip - 1}"
                )
            if op + ctrl + 1 > out_len:
                raise ValueError(
                    f"LZF stream decompresses to more than the declared {out_len} bytes"
                )
            out[op:op + ctrl + 1] = data[ip:end]
            op += ctrl + 1
            ip = end
            continue
        length = ctrl >> 5
        if length == 7:
            if ip + 2 >= n:
                raise ValueError(f"LZF stream truncated inside a back-reference at offset {ip}")
            length = 9 + data[ip + 1]
            ref = op - ((ctrl & 0x1F) << 8) - data[ip + 2] - 1
            ip += 3
        else:
            if ip + 1 >= n:
                raise ValueError(f"LZF stream truncated inside a back-reference at offset {ip}")
            length += 2
            ref = op - ((ctrl & 0x1F) << 8) - data[ip + 1] - 1
            ip += 2
        if ref < 0:
            raise ValueError(f"LZF back-reference points {-ref} bytes before the start of the output")
        if op + length > out_len:
            raise ValueError(f"LZF stream decompresses to more than the declared {out_len} bytes")
        dist = op - ref
        if dist >= length:
            out[op:op + length] = out[ref:ref + length]
        else:
            # Overlapping copy repeats the last `dist` bytes (run-length encoding).
            out[op:op + length] = (out[ref:op] * (length // dist + 1))[:length]
        op += length
    if op != out_len:
        raise ValueError(
            f"LZF stream decompresses to {op} bytes but {out_len} were declared"
        )
    return bytes(out)


def lzf_compress(data) -> bytes:
    """Compress with LZF (greedy, 3-byte hash table); output readable by liblzf and PCL.

    Pure Python, about a microsecond per input byte: meant for small payloads and
    for building test files, not for writing VGA clouds.

    Parameters
    ----------
    data : bytes-like

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
