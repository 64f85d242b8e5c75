"""MCAP chunks read in bounded memory: the Chunk record's header, decompression that cannot exceed
what the chunk declares, and the walk over a chunk's records that stops at the first damaged one.

Why not the ``mcap`` library here: its ``get_chunk_data_stream`` calls ``zstandard.decompress``, which
allocates whatever size the zstd frame header claims (a 630 KB frame claiming 4 GiB allocates 4 GiB),
and ``lz4.frame.decompress`` without an output limit; its ``breakup_chunk`` walks zero-length
records one at a time (4 GiB of zeros never ends). Both are fine on honest files and unbounded on
hostile or damaged ones, so the three steps a reader needs are written here with limits:

* :func:`chunk_header` parses the fixed part of a Chunk record (no copy of its compressed records);
* :func:`decompress_chunk` refuses a chunk whose declared uncompressed size exceeds
  :data:`MAX_CHUNK_BYTES`, and never produces more bytes than the chunk declares (zstd: the frame's
  content size must agree with the declaration, else the output is capped by it; lz4: ``max_length``);
* :func:`walk_records` lists a chunk's records (opcode, start, length) and stops, saying so, at a
  record that is cut off or is not one a chunk may hold (Schema, Channel, Message, each at least as
  long as its fixed fields), so the walk costs at most one step per 23 bytes of trusted data.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass
from typing import Final

import numpy as np

from ..errors import LogReadError

__all__ = ["MAX_CHUNK_BYTES", "ChunkHeader", "OversizeChunkError", "chunk_header", "check_declared", "decompress_chunk",
           "walk_records", "RecordWalk", "OP_SCHEMA", "OP_CHANNEL", "OP_MESSAGE", "OP_CHUNK", "OP_FOOTER",
           "MESSAGE_HEADER_BYTES"]

#: The largest uncompressed chunk read [bytes]. Recorders write chunks of 0.75-4 MiB (rosbag2's
#: default is 768 KiB, the ``mcap`` CLI's 4 MiB); a chunk grows past that only to hold one larger
#: message (a 4K image, a point cloud: tens of MiB). 256 MiB leaves a wide margin above any of
#: these while keeping a reader's peak memory far below a machine's: a chunk declaring more is
#: damaged or hostile (a decompression bomb) and is refused rather than allocated.
MAX_CHUNK_BYTES: Final = 256 * 2**20

OP_SCHEMA: Final = 0x03
OP_CHANNEL: Final = 0x04
OP_MESSAGE: Final = 0x05
OP_CHUNK: Final = 0x06
OP_FOOTER: Final = 0x02
#: channel_id (2), sequence (4), log_time (8), publish_time (8) [bytes]
MESSAGE_HEADER_BYTES: Final = 2 + 4 + 8 + 8
# the fixed fields of the records a chunk may hold [bytes]: a shorter one is damage
_MIN_LENGTH: Final = {OP_SCHEMA: 2 + 4 + 4 + 4, OP_CHANNEL: 2 + 2 + 4 + 4 + 4, OP_MESSAGE: MESSAGE_HEADER_BYTES}
_FIXED: Final = 8 + 8 + 8 + 4  # message start/end time, uncompressed size, uncompressed crc


class OversizeChunkError(LogReadError):
    """A chunk that declares (or decompresses to) more than a reader will hold in memory."""


@dataclass(frozen=True)
class ChunkHeader:
    """The fixed part of an MCAP Chunk record.

    Attributes
    ----------
    message_start_time, message_end_time : int
        Log times of its first and last message [ns].
    uncompressed_size : int
        What its records take once decompressed, as the writer declared [bytes].
    uncompressed_crc : int
        CRC-32 of the uncompressed records; 0 means none was written.
    compression : str
        ``"zstd"``, ``"lz4"`` or ``""``.
    records_offset : int
        Where the compressed records start in the record's body [bytes].
    records_length : int
        Their compressed length [bytes].
    """

    message_start_time: int
    message_end_time: int
    uncompressed_size: int
    uncompressed_crc: int
    compression: str
    records_offset: int
    records_length: int


def chunk_header(body: bytes | memoryview) -> ChunkHeader:
    """Parse the fixed part of a Chunk record's body (what follows its opcode and length).

    Raises
    ------
    ValueError
        The body is too short to hold it, or the compression name is not text.
    """
    if len(body) < _FIXED + 4:
        raise ValueError("chunk record too short")
    start, end, size = np.frombuffer(body[:24], dtype="<u8").tolist()
    crc = int.from_bytes(body[24:28], "little")
    n = int.from_bytes(body[28:32], "little")
    if len(body) < 32 + n + 8:
        raise ValueError("chunk record too short")
    compression = bytes(body[32:32 + n]).decode()
    records_length = int.from_bytes(body[32 + n:40 + n], "little")
    return ChunkHeader(start, end, size, crc, compression, 40 + n, records_length)


def decompress_chunk(header: ChunkHeader, packed: bytes | memoryview, where: str, *,
                     partial: bool = False, limit: int = MAX_CHUNK_BYTES) -> bytes:
    """A chunk's records, decompressed without ever holding more than it declares.

    Parameters
    ----------
    header : ChunkHeader
        The chunk's header (:func:`chunk_header`).
    packed : bytes-like
        Its compressed records (all of them, or, with ``partial``, the part before the file ends).
    where : str
        Names the chunk in messages (``"<file>: chunk at byte N"``).
    partial : bool
        The records are cut off: return what decompresses from them (at most the declared size);
        otherwise all of them must be there and match the chunk's CRC.
    limit : int
        The largest declared size accepted [bytes] (:data:`MAX_CHUNK_BYTES`).

    Raises
    ------
    OversizeChunkError
        The declared size is over ``limit``, or the data decompress to more than declared.
    ValueError, zstandard.ZstdError, RuntimeError
        Damaged or cut-off compressed data, a CRC mismatch, or an unknown compression.
    """
    if not partial and len(packed) < header.records_length:
        raise ValueError("chunk cut off by the end of the file")
    check_declared(header, where, limit=limit)
    declared = header.uncompressed_size
    if header.compression == "":
        out = bytes(packed)
    elif header.compression == "zstd":
        out = _zstd(packed, declared, partial)
    elif header.compression == "lz4":
        import lz4.frame

        # one byte over the declaration tells a lying chunk from an honest one without more memory
        out = lz4.frame.LZ4FrameDecompressor().decompress(bytes(packed), max_length=declared + 1)
    else:
        raise ValueError(f"unknown compression {header.compression!r}")
    if len(out) > declared:
        raise OversizeChunkError(f"{where} decompresses to more than the {_mib(declared)} it declares: "
                                 "refused (a damaged file or a decompression bomb)")
    if not partial and header.uncompressed_crc and zlib.crc32(out) != header.uncompressed_crc:
        raise ValueError("CRC mismatch")
    return out


def check_declared(header: ChunkHeader, where: str, *, limit: int = MAX_CHUNK_BYTES) -> None:
    """Refuse a chunk whose declared uncompressed size, or compressed size, is over ``limit`` [bytes]
    (before reading its records).

    Raises
    ------
    OversizeChunkError
        Naming the chunk (``where``), its declared size and the limit.
    """
    if header.uncompressed_size > limit:
        raise OversizeChunkError(f"{where} declares {_mib(header.uncompressed_size)} uncompressed, over "
                                 f"the {_mib(limit)} a chunk may hold: refused (a damaged file or a "
                                 "decompression bomb)")
    # incompressible data grows by well under 1/64 in zstd and lz4 frames
    if header.records_length > limit + (limit >> 6):
        raise OversizeChunkError(f"{where} holds {_mib(header.records_length)} of compressed records, over "
                                 f"the {_mib(limit)} a chunk may hold: refused (a damaged file)")


def _zstd(packed: bytes | memoryview, declared: int, partial: bool) -> bytes:
    import zstandard

    dctx = zstandard.ZstdDecompressor()
    content = -1 if partial else zstandard.frame_content_size(packed)
    if 0 <= content <= declared:
        return dctx.decompress(packed)
    # streamed, never past the declaration: a cut frame gives what there is; a frame claiming more
    # than the chunk (or not saying) gives at most declared + 1 bytes, which the caller refuses
    # (zstandard's one-shot decompress would allocate the frame's claim)
    reader = dctx.stream_reader(packed, read_across_frames=partial)
    return reader.read(declared + 1)


def _mib(n: int) -> str:
    return f"{n / 2**20:.0f} MiB" if n >= 2**20 else f"{n} bytes"


@dataclass(frozen=True)
class RecordWalk:
    """The records of a chunk's uncompressed data, in order.

    Attributes
    ----------
    opcodes, offsets, lengths : numpy.ndarray
        Each record's opcode, the byte offset of its opcode, and its body's length [bytes].
    complete : bool
        The walk reached the end of the data; False: it stopped at a cut-off or damaged record.
    stop : int
        Where it stopped [bytes].
    """

    opcodes: np.ndarray
    offsets: np.ndarray
    lengths: np.ndarray
    complete: bool
    stop: int


def walk_records(data: bytes | memoryview) -> RecordWalk:
    """List a chunk's records, stopping at the first that is cut off or that a chunk cannot hold.

    A chunk holds Schema, Channel and Message records only (the MCAP specification); anything else
    (a zero-filled region reads as opcode 0 with length 0) means the data cannot be trusted from
    there on, and the walk stops rather than stepping through it nine bytes at a time.
    """
    n = len(data)
    ops: list[int] = []
    offs: list[int] = []
    lens: list[int] = []
    pos = 0
    mv = memoryview(data)
    while pos + 9 <= n:
        op = mv[pos]
        length = int.from_bytes(mv[pos + 1:pos + 9], "little")
        minimum = _MIN_LENGTH.get(op)
        if minimum is None or length < minimum or pos + 9 + length > n:
            break
        ops.append(op)
        offs.append(pos)
        lens.append(length)
        pos += 9 + length
    return RecordWalk(np.array(ops, dtype=np.uint8), np.array(offs, dtype=np.int64),
                      np.array(lens, dtype=np.int64), pos == n, pos)
