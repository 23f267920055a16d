"""NmeaParser.feed vs pynmea2.NMEAStreamReader on the same emulated stream, same run (ratio of CPU time)."""
import time, statistics
import numpy as np, pynmea2
from runtime.drivers.nmea_gps import NmeaParser
from sitl.devices.nmea_gps import gga_sentence, rmc_sentence
rng = np.random.default_rng(1)
stream = b"".join(gga_sentence(t * 0.2, 33.7 + rng.normal(0, 1e-5), -84.4 + rng.normal(0, 1e-5), 300.0)
                  + rmc_sentence(t * 0.2, 33.7, -84.4, 0.4, 45.0) for t in range(10000))
chunks = [stream[i:i + 4096] for i in range(0, len(stream), 4096)]
def ours():
    p = NmeaParser(); n = 0
    for c in chunks:
        n += len(p.feed(c, 0.0))
    return n
def peer():
    r = pynmea2.NMEAStreamReader(errors="ignore"); n = 0
    for c in chunks:
        for m in r.next(c.decode("ascii")):       # the same fields ours extracts, via pynmea2's accessors
            m.timestamp; m.latitude; m.longitude
            if isinstance(m, pynmea2.GGA):
                m.gps_qual; m.num_sats; m.horizontal_dil; m.altitude; m.geo_sep
            else:
                m.status; m.spd_over_grnd; m.true_course
            n += 1
    return n
res = {}
for rep in range(2):
    for name, f in (("ours", ours), ("peer", peer)):
        ts = []
        for _ in range(5):
            t0 = time.process_time(); n = f(); ts.append(time.process_time() - t0)
        res[name] = (statistics.median(ts), n)
for name in res:
    print(f"{name}: {res[name][0]*1e3:.1f} ms CPU for {len(stream)} bytes, {res[name][1]} items, "
          f"{20000 / res[name][0]:.0f} sentences/s")
print(f"ratio ours/peer CPU time: {res['ours'][0] / res['peer'][0]:.2f}")
