"""Numba kernels that scan an MCAP record stream, gather message payloads, and gather records in
time order for the writer.

An MCAP record is ``opcode u8, length u64 (little endian), body[length]`` (MCAP spec, "Records").
A Message record body (opcode 0x05) is ``channel_id u16, sequence u32, log_time u64,
publish_time u64, data``. The scan is sequential (each length says where the next record starts),
which is why it is compiled; everything after it is numpy.
"""
from __future__ import annotations

import numpy as np
from numba import njit

OP_MESSAGE = 5
MESSAGE_HEADER = 22  # channel u16 + sequence u32 + log_time u64 + publish_time u64


@njit(cache=True, nogil=True)
def _u64(buf, p):
    v = np.uint64(0)
    for i in range(8):
        v |= np.uint64(buf[p + i]) << np.uint64(8 * i)
    return v


@njit(cache=True, nogil=True)
def scan_records(buf, start, end):
    """Scan records in ``buf[start:end]``.

    Returns ``(opcode u8[n], body_offset i64[n], body_length i64[n], channel i32[n], log_time i64[n],
    stop)``: ``channel``/``log_time`` are -1/0 for non-message records; ``stop`` is the offset just
    after the last complete record (``< end`` when the stream is truncated inside a record).
    """
    # pass 1: count
    n = 0
    p = start
    while p + 9 <= end:
        ln = _u64(buf, p + 1)
        if ln > np.uint64(end - p - 9):
            break
        p += 9 + np.int64(ln)
        n += 1
    op = np.empty(n, np.uint8)
    off = np.empty(n, np.int64)
    length = np.empty(n, np.int64)
    chan = np.full(n, -1, np.int32)
    logt = np.zeros(n, np.int64)
    p = start
    for i in range(n):
        ln = np.int64(_u64(buf, p + 1))
        op[i] = buf[p]
        off[i] = p + 9
        length[i] = ln
        if buf[p] == OP_MESSAGE and ln >= MESSAGE_HEADER:
            b = p + 9
            chan[i] = np.int32(buf[b]) | (np.int32(buf[b + 1]) << 8)
            logt[i] = np.int64(_u64(buf, b + 6))
        p += 9 + ln
    return op, off, length, chan, logt, p


@njit(cache=True, nogil=True)
def gather_rows(buf, offsets, lengths, width):
    """Copy ``buf[offsets[i]:offsets[i]+lengths[i]]`` into row i of a zero-padded (n, width) matrix."""
    n = offsets.shape[0]
    out = np.zeros((n, width), np.uint8)
    for i in range(n):
        o = offsets[i]
        for j in range(min(lengths[i], width)):
            out[i, j] = buf[o + j]
    return out


@njit(cache=True, nogil=True)
def gather_bytes(srcs, source, offsets, lengths):
    """Concatenate ``srcs[source[i]][offsets[i]:offsets[i]+lengths[i]]`` for i = 0..n-1 into one
    uint8 array: the writer's merge of Message records from several batches (``srcs``, a typed
    list of 1-D uint8 arrays) into time order."""
    n = offsets.shape[0]
    total = 0
    for i in range(n):
        total += lengths[i]
    out = np.empty(total, np.uint8)
    p = 0
    for i in range(n):
        src = srcs[source[i]]
        o = offsets[i]
        ln = lengths[i]
        out[p:p + ln] = src[o:o + ln]
        p += ln
    return out
