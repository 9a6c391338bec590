# Runs under micropython: the player streams a distfile from the filesystem; prints count and CRC-32 of codes.
import json
import struct
import sys
from binascii import crc32

from firmware.player import Player
from protocol import distfile

with open(sys.argv[1], "rb") as f:
    p = Player(distfile.Reader(f))
    p.oneshot()
    xb = [0] * 17
    yb = [0] * 17
    n = 0
    crc = 0
    while True:
        k = p.fill(xb, yb, 17)
        if not k:
            break
        for i in range(k):
            crc = crc32(struct.pack("<HH", xb[i], yb[i]), crc)
        n += k
print(json.dumps({"n": n, "crc": crc & 0xFFFFFFFF}))
