"""A sensor of its own for zentrack, in 30 lines: zenoh and msgpack only (docs/sensors.md).

Reads one scan per line on stdin ("az el" in radians for a bearing sensor, "x y z" in metres for a point sensor;
an empty line: looked, saw nothing), stamps it with this host's clock as it reads it, and publishes it as a
``det`` message on zentrack/<run>/det/<id> through the router at ENDPOINT.
Usage: python third_party_sensor.py RUN ID X,Y,Z SIGMA1,SIGMA2[,SIGMA3] ENDPOINT < scans.txt
"""
import json
import struct
import sys
import time

import msgpack
import zenoh

run, sensor, endpoint = sys.argv[1], int(sys.argv[2]), sys.argv[5]
pose, sigmas = ([float(v) for v in arg.split(",")] for arg in sys.argv[3:5])
m = len(sigmas)  # the measurement's dimension: one standard deviation per component
noise = [sigmas[i] ** 2 if i == j else 0.0 for i in range(m) for j in range(m)]


def f64(values, shape):  # an array: its shape, and its values as little-endian float64 bytes
    return {"shape": shape, "data": struct.pack(f"<{len(values)}d", *values)}


conf = zenoh.Config()
conf.insert_json5("mode", '"client"')
conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
with zenoh.open(conf) as session:
    publisher = session.declare_publisher(f"zentrack/{run}/det/{sensor}")
    for seq, line in enumerate(sys.stdin):
        stamp, z = time.time(), [float(v) for v in line.split()]
        publisher.put(msgpack.packb({
            "v": 2, "kind": "det", "k": seq, "t": stamp, "sender": sensor,  # k: sequence number, t: measured
            "returns": f64(z, [len(z) // m, m]), "pose": f64(pose, [3]), "noise_cov": f64(noise, [m, m]),
            "t_pub": time.time()}, use_bin_type=True))
