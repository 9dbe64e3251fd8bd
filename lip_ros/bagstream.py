"""Raw messages of a rosbag2 MCAP bag for batch processing: chunks read and decompressed ahead, in a thread.

:func:`stream_raw` yields what :func:`lip_ros.bagio.read_raw` yields, in the
same order, faster:

* a background thread decompresses the next chunks (of the memory-mapped
  file) while the caller works on the current one: zstd releases the GIL, and
  with one such call per chunk the thread waits for the GIL once per chunk;
  an uncompressed chunk is copied by numpy, which releases the GIL too (a
  memoryview copy holds it, page faults included: 20 % slower batch runs);
* chunks are decompressed into a few reused buffers: a fresh buffer per
  6.3 MB OS1-128 x 1024 cloud costs as much in page faults as the
  decompression itself (rosbags also copies each message twice);
* a message's ``data`` is a memoryview into its chunk's buffer, not a copy.
  It is valid until the caller asks for a message of the next chunk (it is
  released then: copy it, ``bytes(data)``, to keep it). A numpy array made
  from it keeps that buffer out of reuse while it lives, so data is never
  overwritten under a reader.

Bags it does not handle (sqlite3 storage, per-file or per-message compression,
MCAP without a chunk index, lz4 chunks, chunks that overlap in time) come from
``read_raw``.
"""

from __future__ import annotations

import itertools
import mmap
import queue
import struct
import threading
from collections.abc import Iterable, Iterator
from contextlib import suppress
from dataclasses import dataclass
from operator import itemgetter
from pathlib import Path, PurePath

import numpy as np
import yaml
import zstandard
from isal.isal_zlib import crc32  # zlib's crc32, 10x faster (ISA-L)
from mcap.exceptions import McapError
from mcap.reader import make_reader

from lip_ros.bagio import BagError, RawMessage, read_raw

__all__ = ["stream_raw"]

_CHUNK, _MESSAGE = 0x06, 0x05  # MCAP record opcodes
_RECORD = struct.Struct("<BQ")  # opcode, content length
_CHUNK_HEAD = struct.Struct("<QQQII")  # message start and end time, uncompressed size and crc, compression length
_MESSAGE_HEAD = struct.Struct("<HIQQ")  # channel id, sequence, log time, publish time
_U64 = struct.Struct("<Q")
_BUFFERS = 3  # chunk buffers: one being consumed, up to two read ahead
_YAML_LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)

_Channels = dict[int, tuple[str, str]]  # wanted channel id -> (topic, message type)
_Message = tuple[int, tuple[str, str], int, int]  # log time, (topic, type), start and end of the data in the buffer


@dataclass(frozen=True)
class _File:
    """One MCAP file of a bag: its chunks with wanted messages, in the order their messages come out."""

    path: Path
    channels: _Channels
    chunks: list[tuple[int, int]]  # (offset, length) of the chunk records


def stream_raw(path: str | Path, topics: Iterable[str] | None = None) -> Iterator[RawMessage]:
    """Messages of ``topics`` (default: all) in log-time order, not deserialised, read ahead (see the module)."""
    topics = None if topics is None else list(topics)
    files = _plan(Path(path), None if topics is None else set(topics))
    if files is None:
        yield from read_raw(path, topics)
        return
    free: queue.SimpleQueue[bytearray | None] = queue.SimpleQueue()
    ready: queue.SimpleQueue[tuple[bytearray, list[_Message]] | BaseException | None] = queue.SimpleQueue()
    for _ in range(_BUFFERS):
        free.put(bytearray())
    stop = threading.Event()
    thread = threading.Thread(target=_read_ahead, args=(files, free, ready, stop), name="bag read-ahead", daemon=True)
    thread.start()
    try:
        while (item := ready.get()) is not None:
            if isinstance(item, BaseException):
                raise item
            buf, messages = item
            whole = memoryview(buf)
            views = [whole]
            for log_ns, (topic, msgtype), start, end in messages:
                views.append(whole[start:end])
                yield RawMessage(topic, log_ns, views[-1], msgtype)
            free.put(buf if _reusable(buf, views) else bytearray())
    finally:
        stop.set()
        free.put(None)  # wakes the thread if it waits for a buffer
        thread.join()


def _reusable(buf: bytearray, views: list[memoryview]) -> bool:
    """Release a chunk's views; whether nothing else views its buffer any more (an array made from a message,
    a view of a view), so that it can be reused."""
    for view in views:
        with suppress(BufferError):  # an array still uses it: the buffer stays exported
            view.release()
    if not buf:
        return True
    try:
        del buf[-1]  # a bytearray refuses to resize while it is exported; shrinking by one never reallocates
    except BufferError:
        return False
    buf.append(0)
    return True


def _plan(path: Path, topics: set[str] | None) -> list[_File] | None:
    """The files of a rosbag2 MCAP bag this module can read, None if it cannot (or the bag is unreadable)."""
    try:
        with open(path / "metadata.yaml", encoding="utf-8") as f:
            info = yaml.load(f, Loader=_YAML_LOADER)["rosbag2_bagfile_information"]
        if info["storage_identifier"] != "mcap" or str(info.get("compression_mode") or "none").lower() != "none":
            return None
        files = [_file_plan(path / PurePath(name).name, topics) for name in info["relative_file_paths"]]
    except (OSError, yaml.YAMLError, McapError, struct.error, KeyError, TypeError, ValueError):
        return None
    return None if any(f is None for f in files) else files


def _file_plan(path: Path, topics: set[str] | None) -> _File | None:
    """One MCAP file's plan from its summary; None if it has no chunk index, chunks this module does not
    decompress, or chunks whose messages interleave in time (rosbags merges those)."""
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    if summary is None or not summary.chunk_indexes:
        return None
    channels = {cid: (c.topic, summary.schemas[c.schema_id].name) for cid, c in summary.channels.items()
                if topics is None or c.topic in topics}
    chunks = sorted((c for c in summary.chunk_indexes if channels.keys() & c.message_index_offsets.keys()),
                    key=lambda c: (c.message_start_time, c.chunk_start_offset))
    if any(c.compression not in ("", "zstd") for c in chunks):
        return None
    # rosbags orders messages by (log time, chunk offset): chunk after chunk when each one sorts after the last
    if any((a.message_end_time, a.chunk_start_offset) >= (b.message_start_time, b.chunk_start_offset)
           for a, b in itertools.pairwise(chunks)):
        return None
    return _File(path, channels, [(c.chunk_start_offset, c.chunk_length) for c in chunks])


def _read_ahead(files: list[_File], free: queue.SimpleQueue, ready: queue.SimpleQueue, stop: threading.Event) -> None:
    """The background thread: each chunk into a free buffer, then to ``ready``; None at the end, or the error."""
    try:
        unzip = zstandard.ZstdDecompressor()
        for file in files:
            with open(file.path, "rb") as f, mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as mapped:
                for offset, length in file.chunks:
                    buf = free.get()
                    if buf is None or stop.is_set():
                        return
                    with memoryview(mapped)[offset : offset + length] as record:
                        ready.put(_read_chunk(record, file, offset, buf, unzip))
        ready.put(None)
    except BaseException as exc:  # noqa: BLE001 - handed to the consuming thread, which raises it
        ready.put(exc)


def _read_chunk(record: memoryview, file: _File, offset: int, buf: bytearray, unzip: zstandard.ZstdDecompressor
                ) -> tuple[bytearray, list[_Message]]:
    """The chunk record at ``offset``: its records in ``buf`` (replaced if too small) and its wanted messages
    in log-time order (file order among equal times, as rosbags)."""
    where = f"{file.path}: chunk at offset {offset}"
    try:
        op, _ = _RECORD.unpack_from(record)
        _, _, size, crc, name_len = _CHUNK_HEAD.unpack_from(record, _RECORD.size)
        start = _RECORD.size + _CHUNK_HEAD.size + name_len
        compression = bytes(record[_RECORD.size + _CHUNK_HEAD.size : start]).decode()
        (packed,) = _U64.unpack_from(record, start)
    except (struct.error, UnicodeDecodeError):
        raise BagError(f"{where}: truncated") from None
    if op != _CHUNK or len(record) < start + _U64.size + packed:
        raise BagError(f"{where}: not a whole chunk record")
    if len(buf) <= size:
        buf = bytearray(size + 1)  # one byte more: decompressing past the size shows
    with record[start + _U64.size : start + _U64.size + packed] as src, memoryview(buf)[: size + 1] as out:
        if compression == "zstd":
            with unzip.stream_reader(src, read_size=len(src), read_across_frames=True) as reader:
                got = 0
                while got < len(out) and (n := reader.readinto(out[got:])):  # one call, unless the data is odd
                    got += n
        else:
            got = len(src)
            if got == size:  # numpy copies without the GIL (a memoryview copy would hold it)
                np.copyto(np.frombuffer(out, np.uint8, size), np.frombuffer(src, np.uint8))
        if got != size:
            raise BagError(f"{where}: {got} bytes of records, not {size}")
        if crc and crc32(out[:size]) != crc:
            raise BagError(f"{where}: fails its checksum")
    return buf, _messages(buf, size, file, offset)


def _messages(buf: bytearray, size: int, file: _File, offset: int) -> list[_Message]:
    """The wanted message records among the ``size`` bytes of records in ``buf``, sorted by log time (stable)."""
    found = []
    pos = 0
    while pos < size:
        op, length = _RECORD.unpack_from(buf, pos)
        body, pos = pos + _RECORD.size, pos + _RECORD.size + length
        if pos > size:
            raise BagError(f"{file.path}: chunk at offset {offset} has a truncated record")
        if op == _MESSAGE:
            channel, _, log_ns, _ = _MESSAGE_HEAD.unpack_from(buf, body)
            if channel in file.channels:
                found.append((log_ns, file.channels[channel], body + _MESSAGE_HEAD.size, pos))
    found.sort(key=itemgetter(0))
    return found
