"""The socketcand rawmode wire format: the commands a client sends, the lines the bus sends.

    client: < send 123 2 a 1 >                   a frame onto the bus (ID LEN BYTES, hex)
    server: < frame 123 1700000000.000123 0A01 >  a frame on the bus, with its stamp
    server: < error 008 1700000000.000123 >       an error frame of a SocketCAN class

Pure codec: no sockets, no clock.
"""

from __future__ import annotations

CAN_ERR_PROT = 0x008  # SocketCAN error class: protocol violation (linux/can/error.h)
CAN_ERR_BUSOFF = 0x040  # SocketCAN error class: bus off
MAX_COMMAND = 256  # bytes; a longer unterminated command is garbage

Frame = tuple[int, bool, bytes, object]  # can_id, is_extended_id, data, origin


def take_command(buf: bytearray) -> list[bytes] | None:
    """Remove the first `< ... >` command from `buf` and return its tokens; None if incomplete.

    Bytes before the last `<` preceding the first `>` are dropped with it; a `>`
    without any `<` yields no tokens.
    """
    end = buf.find(b">")
    if end < 0:
        return None
    start = buf.rfind(b"<", 0, end)
    tokens = bytes(buf[start + 1 : end]).split() if start >= 0 else []
    del buf[: end + 1]
    return tokens


def parse_send(tokens: list[bytes], origin: object) -> Frame | None:
    """`send ID LEN B0 B1 ...` (hex) as a frame, or None if malformed; 8 hex digits = extended."""
    try:
        can_id, dlc = int(tokens[1], 16), int(tokens[2], 16)
        data = bytes(int(b, 16) for b in tokens[3:])
    except (IndexError, ValueError):
        return None
    is_ext = len(tokens[1]) == 8
    if dlc > 8 or len(data) != dlc or can_id > (0x1FFFFFFF if is_ext else 0x7FF):
        return None
    return (can_id, is_ext, data, origin)


def frame_line(can_id: int, is_ext: bool, data: bytes, t: float) -> bytes:
    """`< frame ID SEC.USEC DATA >` for a frame stamped `t` (s); 8 hex digits = extended."""
    ident = f"{can_id:08X}" if is_ext else f"{can_id:03X}"
    return f"< frame {ident} {stamp(t)} {data.hex().upper()} >".encode("ascii")


def error_line(error_class: int, t: float) -> bytes:
    """`< error CLASS SEC.USEC >` for an error frame of SocketCAN class `error_class` at `t` (s)."""
    return f"< error {error_class:03X} {stamp(t)} >".encode("ascii")


def stamp(t: float) -> str:
    """socketcand's SEC.USEC."""
    usec = round(t * 1e6)
    return f"{usec // 1_000_000}.{usec % 1_000_000:06d}"
