"""ResponseParser.feed vs the stock clients' node decoding on the same scan stream, same run (ratio of CPU time).

The stream is 100 revolutions of an A1 (36,000 nodes after a SCAN descriptor) in 4096-byte reads.  The peers decode
5-byte slices as the clients' scan loops do once aligned (``rplidar._process_scan``, pyrplidar's
``PyRPlidarMeasurement``), with no resynchronisation or byte accounting; ours does both.
Usage: python benchmarks/rplidar_parser.py
"""
import statistics
import time

from runtime.drivers import rplidar_protocol as P

stream = P.descriptor(P.NODE_LEN, P.MODE_MULTIPLE, P.TYPE_SCAN) + b"".join(
    P.encode_node(k % 360 == 0, 15, (k % 360) * 64, 4000 + k % 997) for k in range(36000))
chunks = [stream[i:i + 4096] for i in range(0, len(stream), 4096)]
body = stream[P.DESCRIPTOR_LEN:]


def ours():
    p = P.ResponseParser()
    return sum(len(p.feed(c)) for c in chunks)


def stock_rplidar():
    import rplidar
    return sum(1 for i in range(0, len(body), 5) if rplidar._process_scan(body[i:i + 5]))


def stock_pyrplidar():
    from pyrplidar_protocol import PyRPlidarMeasurement
    return sum(1 for i in range(0, len(body), 5) if PyRPlidarMeasurement(body[i:i + 5]))


res = {}
for name, fn in (("ours", ours), ("rplidar", stock_rplidar), ("pyrplidar", stock_pyrplidar)):
    ts = []
    for _ in range(5):
        t0 = time.process_time()
        n = fn()
        ts.append(time.process_time() - t0)
    res[name] = (statistics.median(ts), n)
for name, (sec, n) in res.items():
    print(f"{name:>9}: {sec * 1e3:6.1f} ms CPU for {len(stream)} bytes, {n} nodes, {n / sec:,.0f} nodes/s")
for peer in ("rplidar", "pyrplidar"):
    print(f"ratio ours/{peer} CPU time: {res['ours'][0] / res[peer][0]:.2f}")
