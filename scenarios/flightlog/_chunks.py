"""A bulk MCAP writer: Message records built as numpy byte matrices, cut into chunks, one compressor
call per chunk.

MCAP format specification (https://mcap.dev/spec, major version 0), as used here:

* File: ``<Magic><Header><Data section><Summary section><Summary Offset section><Footer><Magic>``.
  A record is ``opcode u8, length u64, body[length]``, little endian.
* Message (0x05): ``channel_id u16, sequence u32, log_time u64, publish_time u64, data``; the caller
  hands over complete records (see :func:`message_header`), already in ``log_time`` order.
* Chunk (0x06): ``message_start_time u64, message_end_time u64, uncompressed_size u64,
  uncompressed_crc u32, compression string, records_length u64, records`` -- ``records`` the
  compressed concatenation of Schema, Channel and Message records; start/end the earliest/latest
  message log_time in it. The CRC is the CRC-32 of the uncompressed records (``zlib.crc32``; the
  spec lets 0 mean "not checked", used here only with ``crc=False``).
* Message Index (0x07), after each chunk, one per channel in the chunk: ``channel_id u16,
  records_length u32, (log_time u64, offset u64)*`` with ``offset`` the byte offset of the Message
  record inside the uncompressed ``records`` of the chunk.
* Chunk Index (0x08, summary): ``message_start_time, message_end_time, chunk_start_offset,
  chunk_length u64, message_index_offsets map<u16, u64> (u32 byte length + entries),
  message_index_length u64, compression string, compressed_size u64, uncompressed_size u64``.
* Summary: Schema and Channel records repeated, Statistics, Chunk Indexes, Attachment Indexes (none),
  Metadata Indexes; Summary Offset records (one per group); Footer with the summary CRC.

Schema and Channel records are put at the start of the first chunk written after they are
registered (as the ``mcap`` library's Writer does), so a stream reader meets them before the first
message of the channel. The small records (Header, Schema, Channel, Metadata, Statistics, indexes,
Footer) are written with the ``mcap`` library's record classes; only Chunk and Message Index records
are built here, because those are the per-message cost. The layout is the one ``mcap.writer.Writer``
1.x produces; readers cannot tell the difference (tests/test_log_format.py reads the files with the
``mcap`` reader (indexed and streamed), ``mcap_ros2``, Rerun and ``scenarios.flightlog.reader``).

Chunking follows ``mcap.writer.Writer``: messages are appended to the open chunk until its size
exceeds ``chunk_size``; the message that crosses the limit is the last one of the chunk. The open
chunk (less than ``chunk_size`` bytes) is kept across :meth:`ChunkWriter.write_messages` calls, so
streaming in small windows still gives full chunks, and memory stays bounded by one chunk.
"""
from __future__ import annotations

import struct
import zlib
from collections import defaultdict

import numpy as np
from numba.typed import List as TypedList
from mcap.data_stream import RecordBuilder
from mcap.opcode import Opcode
from mcap.records import (Channel, ChunkIndex, DataEnd, Footer, Header, Metadata, MetadataIndex, Schema,
                          Statistics, SummaryOffset)

from ._scan import gather_bytes
from .format import strided_view

MAGIC = b"\x89MCAP0\r\n"
OP_MESSAGE = 0x05
MESSAGE_PREFIX = 31  # opcode 1 + length 8 + channel 2 + sequence 4 + log_time 8 + publish_time 8
COMPRESSIONS = ("zstd", "lz4", "")
#: zstd level of the chunks. Level 1 compresses IMU records markedly faster than level 3 (the
#: ``mcap`` library's default) at about the same compression ratio (docs/performance.md).
ZSTD_LEVEL = 1


def record_head(channel_id: int):
    """``head(L)`` -> the first 31 bytes of a Message record with an ``L``-byte payload on channel
    ``channel_id``: opcode 5, length 22 + L, channel, sequence 0, log_time/publish_time 0 (filled
    per message by :func:`set_log_times`). For ``Layout.encode_groups(..., head=...)``."""
    def head(L: int) -> bytes:
        return struct.pack("<BQHIQQ", OP_MESSAGE, 22 + L, channel_id, 0, 0, 0)
    return head


def set_log_times(rows: np.ndarray, t_ns: np.ndarray) -> None:
    """Write log_time = publish_time = ``t_ns`` into Message records ``rows`` ((m, 31 + L) uint8)."""
    strided_view(rows, 15, "<i8", 1)[:, 0] = t_ns
    strided_view(rows, 23, "<i8", 1)[:, 0] = t_ns


def message_header(rows: np.ndarray, channel_id: int, t_ns: np.ndarray) -> None:
    """Fill the first :data:`MESSAGE_PREFIX` columns of ``rows`` ((m, 31 + L) uint8, payloads in
    columns 31:) with Message record headers (:func:`record_head`, :func:`set_log_times`)."""
    rows[:, :MESSAGE_PREFIX] = np.frombuffer(record_head(channel_id)(rows.shape[1] - MESSAGE_PREFIX), np.uint8)
    set_log_times(rows, t_ns)


class ChunkWriter:
    """Write an MCAP file from batches of pre-built Message records (module docstring).

    Parameters
    ----------
    stream : binary file object opened for writing (not closed here).
    chunk_size : uncompressed bytes per chunk (a chunk ends with the message that exceeds it).
    compression : ``"zstd"``, ``"lz4"`` or ``""`` (none).
    crc : write the CRC-32 of each chunk's uncompressed records (else 0: not checked).
    """

    def __init__(self, stream, *, chunk_size: int = 1 << 20, compression: str = "zstd", crc: bool = True):
        if compression not in COMPRESSIONS:
            raise ValueError(f"MCAP chunk compression {compression!r}: expected one of {COMPRESSIONS}")
        self._f = stream
        self._pos = 0  # bytes written so far (the stream may not support tell())
        self.chunk_size = int(chunk_size)
        self.compression = compression
        self.crc = crc
        if compression == "zstd":
            import zstandard
            self._compress = zstandard.ZstdCompressor(level=ZSTD_LEVEL).compress
        elif compression == "lz4":
            import lz4.frame
            self._compress = lz4.frame.compress
        else:
            self._compress = None
        self._schemas: dict[int, Schema] = {}
        self._channels: dict[int, Channel] = {}
        self._defs = RecordBuilder()  # Schema/Channel records waiting for the next chunk
        self._chunk_indexes: list[ChunkIndex] = []
        self._metadata_indexes: list[MetadataIndex] = []
        self._counts: dict[int, int] = defaultdict(int)
        self._n_messages = 0
        self._t_min: int | None = None
        self._t_max: int | None = None
        self._n_metadata = 0
        self._n_chunks = 0
        # open chunk: records (contiguous, < chunk_size bytes) and their times, channels and lengths
        self._tail = np.zeros(0, np.uint8)
        self._tail_t = np.zeros(0, np.int64)
        self._tail_ch = np.zeros(0, np.int64)
        self._tail_len = np.zeros(0, np.int64)

    # ---------------- small records ----------------
    def _write(self, data) -> None:
        self._f.write(data)
        self._pos += memoryview(data).nbytes

    def _write_record(self, record) -> int:
        """Write one record of the ``mcap`` library; returns its length in bytes."""
        rb = RecordBuilder()
        record.write(rb)
        data = rb.end()
        self._write(data)
        return len(data)

    def start(self, profile: str, library: str) -> None:
        self._write(MAGIC)
        self._write_record(Header(profile=profile, library=library))

    def register_schema(self, name: str, encoding: str, data: bytes) -> int:
        sid = len(self._schemas) + 1
        self._schemas[sid] = Schema(id=sid, name=name, encoding=encoding, data=data)
        self._schemas[sid].write(self._defs)
        return sid

    def register_channel(self, topic: str, message_encoding: str, schema_id: int, metadata=None) -> int:
        cid = len(self._channels) + 1
        self._channels[cid] = Channel(id=cid, topic=topic, message_encoding=message_encoding,
                                      schema_id=schema_id, metadata=dict(metadata or {}))
        self._channels[cid].write(self._defs)
        return cid

    def add_metadata(self, name: str, data: dict[str, str]) -> None:
        offset = self._pos
        length = self._write_record(Metadata(name=name, metadata=data))
        self._metadata_indexes.append(MetadataIndex(offset=offset, length=length, name=name))
        self._n_metadata += 1

    # ---------------- messages ----------------
    def write_messages(self, t_ns: np.ndarray, channel: np.ndarray, length: np.ndarray, buf,
                       offsets: np.ndarray | None = None, source: np.ndarray | None = None) -> None:
        """Append Message records in their final order (nondecreasing ``t_ns``).

        ``buf`` is one 1-D uint8 array holding the records back to back in this order (``offsets``
        None), or a list of 1-D uint8 arrays with record i at ``buf[source[i]][offsets[i]:][:length[i]]``
        (``source`` None: all in ``buf[0]``). ``channel`` and ``t_ns`` are the channel id and
        log_time of each record. Full chunks are written now; the rest stays in the open chunk.
        """
        n = len(t_ns)
        if n == 0:
            return
        t_ns = np.asarray(t_ns, np.int64)
        channel = np.asarray(channel, np.int64)
        length = np.asarray(length, np.int64)
        self._n_messages += n
        self._t_min = int(t_ns[0]) if self._t_min is None else min(self._t_min, int(t_ns.min()))
        self._t_max = int(t_ns[-1]) if self._t_max is None else max(self._t_max, int(t_ns.max()))
        for c, k in zip(*np.unique(channel, return_counts=True)):
            self._counts[int(c)] += int(k)
        if offsets is None:
            ends = np.cumsum(length)  # end of each record in buf

            def records(i, j):
                return buf[0 if i == 0 else int(ends[i - 1]):int(ends[j - 1])]
        else:
            srcs = TypedList(buf)
            source = np.zeros(n, np.int64) if source is None else np.asarray(source, np.int64)
            offsets = np.asarray(offsets, np.int64)

            def records(i, j):
                return gather_bytes(srcs, source[i:j], offsets[i:j], length[i:j])
        tail_n = len(self._tail)
        vend = tail_n + np.cumsum(length)  # end of each record in the open chunk + these records
        i = 0  # first record not yet in a written chunk
        base = 0  # position of record i in the virtual stream (open chunk followed by these records)
        while True:
            j = int(np.searchsorted(vend, base + self.chunk_size, side="right"))
            if j >= n:
                break
            parts = [memoryview(records(i, j + 1))]
            t, ch, ln = t_ns[i:j + 1], channel[i:j + 1], length[i:j + 1]
            if i == 0 and tail_n:
                parts.insert(0, memoryview(self._tail))
                t = np.concatenate([self._tail_t, t])
                ch = np.concatenate([self._tail_ch, ch])
                ln = np.concatenate([self._tail_len, ln])
            self._write_chunk(parts, t, ch, ln)
            if i == 0:
                self._clear_tail()
            base = int(vend[j])
            i = j + 1
        if i < n:  # the rest joins the open chunk (copied: ``buf`` is the caller's)
            rest = np.array(records(i, n), copy=True)
            self._tail = np.concatenate([self._tail, rest]) if len(self._tail) else rest
            self._tail_t = np.concatenate([self._tail_t, t_ns[i:]])
            self._tail_ch = np.concatenate([self._tail_ch, channel[i:]])
            self._tail_len = np.concatenate([self._tail_len, length[i:]])

    def _clear_tail(self):
        self._tail = np.zeros(0, np.uint8)
        self._tail_t = np.zeros(0, np.int64)
        self._tail_ch = np.zeros(0, np.int64)
        self._tail_len = np.zeros(0, np.int64)

    def _write_chunk(self, parts: list, t: np.ndarray, ch: np.ndarray, ln: np.ndarray) -> None:
        """Compress and write one Chunk record (Schema/Channel records not yet written first), then
        its Message Index records; remember its Chunk Index."""
        defs = self._defs.end()
        if defs:
            parts = [defs] + parts
        records = parts[0] if len(parts) == 1 else b"".join(parts)
        size = memoryview(records).nbytes
        data = records if self._compress is None else self._compress(records)
        crc = zlib.crc32(records) if self.crc else 0
        comp = self.compression.encode()
        csize = memoryview(data).nbytes
        t0, t1 = int(t.min()), int(t.max())
        head = struct.pack("<BQQQQI", Opcode.CHUNK, 8 + 8 + 8 + 4 + 4 + len(comp) + 8 + csize, t0, t1, size, crc)
        head += struct.pack("<I", len(comp)) + comp + struct.pack("<Q", csize)
        chunk_start = self._pos
        self._write(head)
        self._write(data)
        chunk_length = self._pos - chunk_start
        # Message Index records: (log_time, offset in the uncompressed records) per channel
        off = len(defs) + np.concatenate([[0], np.cumsum(ln[:-1])])
        index_offsets: dict[int, int] = {}
        index_start = self._pos
        pieces = []
        pos = index_start
        for c in np.unique(ch).tolist():
            sel = ch == c
            k = int(np.count_nonzero(sel))
            entries = np.empty((k, 2), "<u8")
            entries[:, 0] = t[sel]
            entries[:, 1] = off[sel]
            rec = struct.pack("<BQHI", Opcode.MESSAGE_INDEX, 2 + 4 + 16 * k, c, 16 * k) + entries.tobytes()
            index_offsets[c] = pos
            pos += len(rec)
            pieces.append(rec)
        self._write(b"".join(pieces))
        self._chunk_indexes.append(ChunkIndex(
            message_start_time=t0, message_end_time=t1, chunk_start_offset=chunk_start, chunk_length=chunk_length,
            message_index_offsets=index_offsets, message_index_length=pos - index_start,
            compression=self.compression, compressed_size=csize, uncompressed_size=size))
        self._n_chunks += 1

    # ---------------- end ----------------
    def finish(self) -> None:
        """Write the open chunk, Data End, the summary (schemas, channels, statistics, chunk and
        metadata indexes, summary offsets) and the footer. Does not close the stream."""
        if len(self._tail_t):
            self._write_chunk([memoryview(self._tail)], self._tail_t, self._tail_ch, self._tail_len)
            self._clear_tail()
        defs = self._defs.end()
        if defs:  # registered but never used by a message: top-level records in the data section
            self._write(defs)
        self._write_record(DataEnd(data_section_crc=0))
        summary_start = self._pos
        sb = RecordBuilder()
        offsets = []

        def group(opcode, records):
            g0 = sb.count
            for r in records:
                r.write(sb)
            offsets.append(SummaryOffset(group_opcode=opcode, group_start=summary_start + g0,
                                         group_length=sb.count - g0))

        group(Opcode.SCHEMA, self._schemas.values())
        group(Opcode.CHANNEL, self._channels.values())
        stats = Statistics(
            message_count=self._n_messages, schema_count=len(self._schemas), channel_count=len(self._channels),
            attachment_count=0, metadata_count=self._n_metadata, chunk_count=self._n_chunks,
            message_start_time=self._t_min or 0, message_end_time=self._t_max or 0,
            channel_message_counts=dict(self._counts))
        group(Opcode.STATISTICS, [stats])
        group(Opcode.CHUNK_INDEX, self._chunk_indexes)
        group(Opcode.ATTACHMENT_INDEX, [])
        group(Opcode.METADATA_INDEX, self._metadata_indexes)
        summary_offset_start = summary_start + sb.count
        for o in offsets:
            o.write(sb)
        summary = sb.end()
        crc = zlib.crc32(summary)
        crc = zlib.crc32(struct.pack("<BQQQ", Opcode.FOOTER, 8 + 8 + 4, summary_start, summary_offset_start), crc)
        self._write(summary)
        self._write_record(Footer(summary_start=summary_start, summary_offset_start=summary_offset_start,
                                  summary_crc=crc))
        self._write(MAGIC)
