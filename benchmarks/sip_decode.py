"""ARCOS standard-SIP decode rate: ours beside a straightforward struct-based decoder (one struct.unpack_from per
field, as a hand-written client reads it) and, when installed, Soar's decode_packet; all measured in this run.

    PYTHONPATH=. python benchmarks/sip_decode.py
"""
import struct
import timeit

from runtime.drivers import arcos_protocol as P

SIP = P.Sip(x=1234, y=4321, th=1024, left_vel=300, right_vel=310, battery_dv=128, stall_bumpers=0, control=1024,
            flags=0x07, compass=0, sonars=tuple((n, 500 + 100 * n) for n in range(16)), moving=True,
            grip_anport=0, analog=0, digin=0, digout=0, battery_x10=128, charge_state=0, rot_vel_x10=25,
            fault_flags=0, lat_vel=0, temperature=25, state_of_charge=90, uc_time_us=123456789, flags3=0)
BODY = P.encode_sip(SIP)
WIRE = P.frame(BODY)
HEAD = [("x", "<H"), ("y", "<H"), ("th", "<h"), ("left_vel", "<h"), ("right_vel", "<h"), ("battery", "<B"),
        ("stall", "<H"), ("control", "<h"), ("flags", "<H"), ("compass", "<B")]
TAIL = [(n, "<" + c) for n, c in P.SIP_TAIL]


def struct_decoder(body: bytes) -> dict:
    """The straightforward way: one unpack_from per field, walking an offset."""
    out, i = {}, 1
    for name, fmt in HEAD:
        out[name] = struct.unpack_from(fmt, body, i)[0]
        i += struct.calcsize(fmt)
    out["x"] &= 0x7FFF
    out["y"] &= 0x7FFF
    n = body[i]
    i += 1
    sonars = []
    for _ in range(n):
        sonars.append((body[i], struct.unpack_from("<H", body, i + 1)[0]))
        i += 3
    out["sonars"] = sonars
    for name, fmt in TAIL:
        size = struct.calcsize(fmt)
        if len(body) - i < size:
            break
        out[name] = struct.unpack_from(fmt, body, i)[0]
        i += size
    return out


def rate(fn, number=20000) -> float:
    """Calls per second, best of 5."""
    return number / min(timeit.repeat(fn, number=number, repeat=5))


def main() -> None:
    assert P.decode_sip(BODY) == SIP and struct_decoder(BODY)["flags3"] == 0
    ours = rate(lambda: P.decode_sip(BODY))
    peer = rate(lambda: struct_decoder(BODY))
    print(f"standard SIP, {len(WIRE)} bytes on the wire (16 sonar readings, whole tail)")
    print(f"  struct-based decoder : {peer:10.0f} SIP/s")
    print(f"  ours (decode_sip)    : {ours:10.0f} SIP/s   ratio ours/struct {ours / peer:.2f}")
    stream = WIRE * 200
    framed = 200 * rate(lambda: [P.decode_sip(b) for b in P.PacketParser().feed(stream)], number=20)
    print(f"  ours, framing + checksum + decode from a byte stream: {framed:10.0f} SIP/s "
          f"(ratio to the struct decoder alone {framed / peer:.2f}; a robot sends 10 SIP/s)")
    try:
        from soar.robot.arcos import decode_packet
    except ImportError:
        print("  Soar not installed: its decoder not measured")
        return
    wire = list(WIRE)
    soar = rate(lambda: decode_packet(wire))
    print(f"  Soar decode_packet   : {soar:10.0f} SIP/s   ratio ours/Soar {ours / soar:.2f} (Soar stops at ROTVEL)")


if __name__ == "__main__":
    main()
