"""Create OI decoding speed beside pycreate2's decoder, measured in the same run (ratios printed)."""
import timeit, os
from pycreate2.packets import SensorPacketDecoder
from runtime.drivers import create_oi_protocol as P
data = bytes(os.urandom(80))
n = 20000
t_peer = min(timeit.repeat(lambda: SensorPacketDecoder(data), number=n, repeat=5)) / n
t_mine = min(timeit.repeat(lambda: P.decode_packet(100, data), number=n, repeat=5)) / n
print(f"packet 100 decode: pycreate2 {t_peer*1e6:.1f} us, create_oi_protocol {t_mine*1e6:.1f} us, ratio mine/peer {t_mine/t_peer:.2f}")
frame = P.build_stream_frame([(7, b'\x00'), (35, b'\x02'), (3, bytes(10)), (43, b'\x01\x02'), (44, b'\x03\x04')])
stream = frame * 1000
def parse():
    P.StreamParser().feed(stream)
t = min(timeit.repeat(parse, number=5, repeat=5)) / 5
print(f"stream parser: {len(stream)/t/1e6:.2f} MB/s, {1000/t:.0f} driver frames/s ({len(frame)} B each)")
frame100 = P.build_stream_frame([(100, bytes(80))])
t_f = min(timeit.repeat(lambda: P.StreamParser().feed(frame100 * 100), number=20, repeat=5)) / 2000
print(f"stream frame with packet 100: {t_f*1e6:.1f} us/frame, ratio to pycreate2 packet-100 decode {t_f/t_peer:.2f}")
