"""MAVLink FTP for a robot that serves no files: every request is answered at once, never left to time out.

The robot does not advertise MAV_PROTOCOL_CAPABILITY_FTP, but MAVProxy's ``param`` module still starts
with an FTP download of ``@PARAM/param.pck`` and, unanswered, retries the open for ~3 s before it falls
back to PARAM_REQUEST_LIST (mavproxy_ftp.idle_task: a retry every 1 s, the get fails after the third).
A NAK ``FileNotFound`` to the OpenFileRO fails the get at once (handle_open_RO_reply ->
terminate_session -> the param module's callback(None) -> ``ftp_failed``).

FILE_TRANSFER_PROTOCOL.payload layout (mavlink devguide services/ftp.md; MAVProxy FTP_OP.pack/op_parse,
``struct "<HBBBBBBI"``), 12 header bytes then data:

    0-1 seq_number (uint16)  2 session  3 opcode  4 size  5 req_opcode  6 burst_complete  7 padding
    8-11 offset (uint32)     12.. data (a NAK's data[0] is the MAV_FTP_ERR code, size 1)

A reply carries ``seq_number`` + 1, the request's ``session``, opcode ACK (128) or NAK (129) and
``req_opcode`` = the request's opcode.  Answers here, all true of a server with no files and no sessions:
None and ResetSessions -> ACK; reads, lists, renames, removes, CRCs -> NAK FileNotFound; session
operations (read/burst/write/terminate) -> NAK InvalidSession; creating or opening for write -> NAK
FileProtected; anything else -> NAK UnknownCommand.  A reply (ACK or NAK) is never answered.
"""
from __future__ import annotations

import struct
from dataclasses import dataclass

HEADER = struct.Struct("<HBBBBBBI")
PAYLOAD_LEN = 251                       # FILE_TRANSFER_PROTOCOL.payload is uint8_t[251]

# MAV_FTP_OPCODE
OP_NONE, OP_TERMINATE_SESSION, OP_RESET_SESSIONS, OP_LIST_DIRECTORY = 0, 1, 2, 3
OP_OPEN_FILE_RO, OP_READ_FILE, OP_CREATE_FILE, OP_WRITE_FILE = 4, 5, 6, 7
OP_REMOVE_FILE, OP_CREATE_DIRECTORY, OP_REMOVE_DIRECTORY, OP_OPEN_FILE_WO = 8, 9, 10, 11
OP_TRUNCATE_FILE, OP_RENAME, OP_CALC_FILE_CRC32, OP_BURST_READ_FILE = 12, 13, 14, 15
OP_LIST_DIRECTORY_WITH_TIME = 16
OP_ACK, OP_NAK = 128, 129
# MAV_FTP_ERR
ERR_INVALID_SESSION, ERR_UNKNOWN_COMMAND, ERR_FILE_PROTECTED, ERR_FILE_NOT_FOUND = 4, 7, 9, 10

_ACKED = frozenset({OP_NONE, OP_RESET_SESSIONS})
_NACK = {
    **dict.fromkeys((OP_LIST_DIRECTORY, OP_OPEN_FILE_RO, OP_REMOVE_FILE, OP_REMOVE_DIRECTORY, OP_TRUNCATE_FILE,
                     OP_RENAME, OP_CALC_FILE_CRC32, OP_LIST_DIRECTORY_WITH_TIME), ERR_FILE_NOT_FOUND),
    **dict.fromkeys((OP_TERMINATE_SESSION, OP_READ_FILE, OP_WRITE_FILE, OP_BURST_READ_FILE), ERR_INVALID_SESSION),
    **dict.fromkeys((OP_CREATE_FILE, OP_CREATE_DIRECTORY, OP_OPEN_FILE_WO), ERR_FILE_PROTECTED),
}


@dataclass(frozen=True)
class FtpHeader:
    seq: int
    session: int
    opcode: int
    size: int
    req_opcode: int
    burst_complete: int
    offset: int


def parse(payload) -> FtpHeader | None:
    """The header of a FILE_TRANSFER_PROTOCOL payload (bytes or a list of ints), None if it is too short
    or not bytes."""
    try:
        raw = bytes(payload[:HEADER.size])
    except (TypeError, ValueError):
        return None
    if len(raw) < HEADER.size:
        return None
    seq, session, opcode, size, req_opcode, burst, _pad, offset = HEADER.unpack(raw)
    return FtpHeader(seq, session, opcode, size, req_opcode, burst, offset)


def encode(h: FtpHeader, data: bytes = b"") -> list[int]:
    """``h`` and ``data`` as the 251-int payload pymavlink's encoder takes (zero padded)."""
    out = HEADER.pack(h.seq & 0xFFFF, h.session & 0xFF, h.opcode & 0xFF, h.size & 0xFF, h.req_opcode & 0xFF,
                      h.burst_complete & 0xFF, 0, h.offset & 0xFFFFFFFF) + bytes(data)
    return list(out[:PAYLOAD_LEN].ljust(PAYLOAD_LEN, b"\0"))


def answer(request: FtpHeader) -> tuple[FtpHeader, bytes] | None:
    """(reply header, reply data) for ``request``; None for a request that is itself a reply."""
    if request.opcode in (OP_ACK, OP_NAK):
        return None
    seq = (request.seq + 1) & 0xFFFF
    if request.opcode in _ACKED:
        return FtpHeader(seq, request.session, OP_ACK, 0, request.opcode, 0, 0), b""
    err = _NACK.get(request.opcode, ERR_UNKNOWN_COMMAND)
    return FtpHeader(seq, request.session, OP_NAK, 1, request.opcode, 0, 0), bytes([err])


def reply_payload(payload) -> list[int] | None:
    """The reply payload for a request payload, or None when there is nothing to answer."""
    h = parse(payload)
    if h is None:
        return None
    out = answer(h)
    return None if out is None else encode(*out)
