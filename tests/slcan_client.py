"""An unmodified SLCAN client (python-can's `slcan` interface) on the emulated board's
CAN port: opens the bus at 1 Mbit/s, receives frames, sends one control frame (angular
decimation k=2, token 0x5A), receives more, and prints one JSON object.

usage: python3 slcan_client.py socket://127.0.0.1:PORT SECONDS
"""
import json
import sys
import time

import can

url, seconds = sys.argv[1], float(sys.argv[2])
bus = can.Bus(interface="slcan", channel=url, bitrate=1_000_000, sleep_after_open=0.2)
version = bus.get_version(2.0)
serial = bus.get_serial_number(2.0)
ids = {}
answers = []
frames = 0
sent = False
start = time.time()
while time.time() - start < seconds:
    if not sent and time.time() - start > seconds / 2:
        # Control frame to node 0 (ID 0x100): opcode 0x14 angular decimation, token,
        # k = 2, mode 0 (every k-th point).
        bus.send(can.Message(arbitration_id=0x100, data=[0x14, 0x5A, 2, 0], is_extended_id=False))
        sent = True
    msg = bus.recv(0.1)
    if msg is None:
        continue
    frames += 1
    key = f"{msg.arbitration_id:03X}"
    ids[key] = ids.get(key, 0) + 1
    if msg.arbitration_id == 0x110:
        answers.append(msg.data.hex())
bus.shutdown()
print(json.dumps({"version": list(version), "serial": serial, "frames": frames,
                  "ids": ids, "answers": answers}))
