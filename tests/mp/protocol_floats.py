# Runs under micropython: the pure core's encoder (what the firmware's stream and CAN links use) refuses
# non-finite floats and floats beyond float32 or a field's declared range, with a ValueError naming the field.
import json

from protocol import core

cases = []
for name, field, v in (("RW_CMD", "torque", float("inf")), ("RW_CMD", "torque", -float("inf")),
                       ("RW_CMD", "torque", float("nan")), ("RW_CMD", "torque", 1e40),
                       ("RW_CMD", "torque", -1e39), ("RW_TLM", "speed", 10 ** 50),
                       ("STARTRACKER", "q0", 1.5), ("BEACON", "uz", float("inf"))):
    try:
        core.encode_payload(name, **{field: v})
        cases.append("accepted")
    except ValueError as e:
        cases.append(str(e).split(" ")[0].rstrip(":"))
ok = core.encode_payload("RW_CMD", torque=3.4028234663852886e38, enable=1)
print(json.dumps({"cases": cases, "max_ok": ok.hex()}))
